"""Benchmark scripts refuse settings they cannot run, in one usage line, before any work."""

import pytest

from tests.conftest import load_benchmark


def test_fidelity_table_refuses_fewer_particles_than_its_subsample(capsys):
    ft = load_benchmark("fidelity_table")
    with pytest.raises(SystemExit) as exc:
        ft.main(["--particles", "100", "--no-results"])
    assert exc.value.code == 2
    assert "--particles: at least 3000" in capsys.readouterr().err
