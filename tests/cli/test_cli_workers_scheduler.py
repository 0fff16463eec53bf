"""`--workers` with `--scheduler` (whatif, identify, calibrate): the scheduler's own workers run the tasks,
so a local worker count would do nothing. It was silently ignored; it is refused, in one line, before any
work."""

from __future__ import annotations

import pytest

from bmctl.cli import main

from ..conftest import ROOT, card_path

LAB = str(card_path("alni-1to1-300rpm-lab"))
SCHEDULE = str(ROOT / "scenarios" / "schedule-lab-300rpm-12h.toml")
ADDRESS = "tcp://127.0.0.1:8786"
MESSAGE = "bmctl: error: --workers: sets the local Dask workers, which --scheduler replaces"


def _no_work(*_args, **_kwargs):
    raise AssertionError("work started before the flags were checked")


@pytest.mark.parametrize("workers", ["0", "3"])
@pytest.mark.parametrize("command", [
    ["whatif", LAB, SCHEDULE],
    ["identify", LAB, "--quick"],
    ["calibrate", LAB, "history.toml"],
])
def test_workers_with_a_scheduler_is_refused_before_any_work(tmp_path, capsys, monkeypatch, command, workers):
    import bmctl.config
    from bmctl import parallel

    monkeypatch.setattr(bmctl.config, "load_card", _no_work)  # the first thing each command reads
    monkeypatch.setattr(parallel, "client_for", _no_work)
    out = tmp_path / ("c.toml" if command[0] == "identify" else "o")
    rc = main([*command, "--scheduler", ADDRESS, "--workers", workers, "--out", str(out)])
    stdout, err = capsys.readouterr()
    assert rc == 2 and err == MESSAGE + "\n" and stdout == ""
    assert list(tmp_path.iterdir()) == []


def test_a_scheduler_alone_still_runs(tmp_path, capsys, monkeypatch):
    """Without --workers the scheduler is used as before (here a serial stand-in for it)."""
    from bmctl import parallel

    asked = []

    def record(scheduler=None, workers=None, processes=True):
        asked.append((scheduler, workers))
        return None

    monkeypatch.setattr(parallel, "client_for", record)
    sched = tmp_path / "s.toml"
    sched.write_text('name = "s"\n[[segment]]\nhours = 0.5\nrpm = 300\n', encoding="utf-8")
    rc = main(["whatif", LAB, str(sched), "--seeds", "2", "--particles", "200", "--scheduler", ADDRESS,
               "--out", str(tmp_path / "o")])
    assert rc == 0, capsys.readouterr().err
    assert asked == [(ADDRESS, None)]
