"""`bmctl verify`: its four outputs are one set (the checks themselves: tests/validation/test_verification.py).

The checks are replaced by a one-row stand-in (seconds of Monte Carlo runs otherwise); the figures
by writers that go through :func:`bmctl.io.atomic_path`, as the real ones do (:func:`bmctl.io.savefig`).
"""

from __future__ import annotations

import pytest

from bmctl.cli import main

from ..conftest import card_path

LAB = str(card_path("alni-1to1-300rpm-lab"))
OUTPUTS = ["analytic.png", "reference.png", "verification.csv", "verification.txt"]


@pytest.fixture
def instant_checks(monkeypatch):
    """`verify` without its runs: one passing row, figures of a few bytes."""
    from bmctl import io
    from bmctl.validation import verify as V

    def figure(report, path):
        with io.atomic_path(path) as tmp:
            tmp.write_bytes(b"figure")

    monkeypatch.setattr(V, "run_all", lambda settings, seed, cards, progress: object())
    monkeypatch.setattr(V, "rows", lambda report: [("analytic", "case", 500, "N rel. error (rms)", "0.0100",
                                                     "0.0200", "pass")])
    monkeypatch.setattr(V, "analytic_figure", figure)
    monkeypatch.setattr(V, "reference_figure", figure)


def _verify(out):
    return main(["verify", "--quick", "--models", LAB, "--out", str(out), "--no-progress"])


def test_verify_writes_its_four_outputs(tmp_path, capsys, instant_checks):
    out = tmp_path / "v"
    assert _verify(out) == 0, capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == OUTPUTS
    assert "1 of 1 checks passed" in (out / "verification.txt").read_text(encoding="utf-8")


def test_an_output_that_cannot_be_written_leaves_none_of_the_set(tmp_path, capsys, instant_checks):
    """A folder where analytic.png goes: exit 2 naming it, and verification.txt and .csv were left beside it."""
    out = tmp_path / "v"
    (out / "analytic.png").mkdir(parents=True)
    rc = _verify(out)
    stdout, err = capsys.readouterr()
    assert rc == 2 and err.count("\n") == 1 and err.startswith(f"bmctl: error: {out / 'analytic.png'}: "), err
    assert "Traceback" not in err and stdout == ""
    assert [p.name for p in out.iterdir()] == ["analytic.png"]  # the folder, and nothing new (no temporary file)
    assert not any((out / "analytic.png").iterdir())


def test_an_earlier_set_is_kept_whole_when_a_late_output_fails(tmp_path, capsys, instant_checks):
    """A failure at the last figure leaves the earlier run's table, not a new table beside old figures."""
    out = tmp_path / "v"
    out.mkdir()
    for name in ("verification.txt", "verification.csv", "analytic.png"):
        (out / name).write_text("earlier\n", encoding="utf-8")
    (out / "reference.png").mkdir()
    assert _verify(out) == 2
    assert f"{out / 'reference.png'}: " in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == OUTPUTS
    for name in ("verification.txt", "verification.csv", "analytic.png"):
        assert (out / name).read_text(encoding="utf-8") == "earlier\n", name
