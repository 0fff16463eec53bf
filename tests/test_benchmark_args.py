"""Benchmark scripts refuse settings they cannot run, in one usage line, before any work."""

import pytest

from tests.conftest import load_benchmark


def test_fidelity_table_refuses_fewer_particles_than_its_subsample(capsys):
    ft = load_benchmark("fidelity_table")
    with pytest.raises(SystemExit) as exc:
        ft.main(["--particles", "100", "--no-results"])
    assert exc.value.code == 2
    assert "--particles: at least 3000" in capsys.readouterr().err


def test_bench_measure_records_how_to_make_its_baseline_again(tmp_path):
    """A side-by-side run names the baseline's commit: the folder itself is gone afterwards."""
    import shutil
    import subprocess
    if shutil.which("git") is None:
        pytest.skip("git not installed")
    bm = load_benchmark("bench_measure")
    repo = tmp_path / "base"
    repo.mkdir()
    env = {"GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@t", "GIT_COMMITTER_NAME": "t",
           "GIT_COMMITTER_EMAIL": "t@t", "PATH": __import__("os").environ["PATH"]}
    for cmd in (["init", "-q"], ["commit", "-q", "--allow-empty", "-m", "x"]):
        subprocess.run(["git", "-C", str(repo), *cmd], check=True, env=env)
    head = subprocess.run(["git", "-C", str(repo), "rev-parse", "--short=7", "HEAD"],
                          capture_output=True, text=True, check=True).stdout.strip()
    assert bm._checkout_commit(repo) == head and len(head) == 7
    assert bm._checkout_commit(tmp_path / "missing") is None
