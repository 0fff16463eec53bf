"""README.md's commands run on the shipped files: every ``bmctl`` line parses, every file it
names exists and loads (quick), and the whole list runs in order in a scratch folder (slow)."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import numpy as np
import pytest

from bmctl.cli import build_parser, main

from .conftest import ROOT

README = ROOT / "README.md"
SHIPPED = ("models", "controllers", "scenarios", "examples")


def _blocks(text: str, lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", text, re.S)


def readme_commands() -> list[list[str]]:
    """The ``bmctl ...`` lines of README's bash blocks as argument lists (comments dropped)."""
    out = []
    for block in _blocks(README.read_text(encoding="utf-8"), "bash"):
        for line in block.splitlines():
            if line.startswith("bmctl "):
                out.append(shlex.split(line, comments=True)[1:])
    return out


COMMANDS = readme_commands()


def _shipped_paths(argv: list[str]) -> list[Path]:
    return [ROOT / a for a in argv if a.split("/")[0] in SHIPPED]


def test_readme_has_a_command_for_every_shipped_example_and_each_subcommand_once():
    assert len(COMMANDS) >= 15
    named = {a for argv in COMMANDS for a in argv}
    for p in (ROOT / "examples").rglob("*"):
        if p.is_file() and p.suffix in (".csv", ".tif", ".toml") and p.parent.name != "samples" \
                and p.name != "readings.csv":  # the readings are given as --temperatures
            assert str(p.relative_to(ROOT)) in named, f"{p.name} is shipped but no README command uses it"
    used = {argv[0] for argv in COMMANDS}
    assert {"simulate", "measure", "compare", "estimate", "calibrate", "design", "whatif", "trial", "campaign"} <= used


@pytest.mark.parametrize("argv", COMMANDS, ids=[" ".join(a[:2]) for a in COMMANDS])
def test_readme_command_parses_and_its_files_exist_and_load(argv):
    from bmctl.calibrate.history import load_history
    from bmctl.config import load_card, load_schedule
    from bmctl.control.config import load_controller
    from bmctl.measure.scale import scale_from_metadata
    from bmctl.measure.tables import read_table
    from bmctl.scenario import load_scenario

    build_parser().parse_args(argv)  # flags and values as the CLI takes them (refusals are InputErrors)
    for p in _shipped_paths(argv):
        assert p.exists(), f"README names {p.relative_to(ROOT)}, which is not shipped"
        top = p.relative_to(ROOT).parts[0]
        if p.is_dir():
            tables = sorted(p.glob("*.csv"))
            assert tables and all(len(read_table(t)) >= 100 for t in tables)
        elif p.suffix == ".csv":
            assert len(read_table(p)) >= 100
        elif p.suffix == ".tif":
            sc = scale_from_metadata(p)
            assert sc is not None and sc.um_per_px > 0  # measure reads the pixel size from the file
        elif top == "models":
            load_card(p)
        elif top == "controllers":
            load_controller(p)
        elif p.name.startswith("schedule-"):
            load_schedule(p)
        elif top == "scenarios":
            load_scenario(p)
        elif p.name.startswith("history-"):
            h = load_history(p)
            assert len(h.samples) >= 3


def test_example_samples_match_the_readings_and_times_the_readme_gives():
    """The README's --times and --temperatures are the example files' own."""
    import csv

    est = next(a for a in COMMANDS if a[0] == "estimate")
    times = [float(x) for x in est[est.index("--times") + 1].split(",")]
    temps = [float(x) for x in est[est.index("--temperatures") + 1].split(",")]
    with open(ROOT / "examples" / "readings.csv", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert times == [float(r["t_h"]) for r in rows] and temps == [float(r["temperature_c"]) for r in rows]
    assert len(sorted((ROOT / "examples" / "samples").glob("*.csv"))) == len(times)


@pytest.mark.slow
def test_readme_commands_and_python_api_run_on_the_shipped_files(tmp_path, monkeypatch, capsys):
    """Every README command in order, in a scratch folder holding the shipped folders (outputs
    land there), then the Python API block."""
    for name in SHIPPED:
        (tmp_path / name).symlink_to(ROOT / name)
    monkeypatch.chdir(tmp_path)
    for argv in COMMANDS:
        extra = ["--workers", "1"] if argv[0] in ("calibrate", "whatif") and "--workers" not in argv else []
        assert main(argv + extra) == 0, " ".join(argv)
    out = capsys.readouterr().out
    assert (tmp_path / "run1" / "report.html").exists() and (tmp_path / "out" / "lab" / "moments.csv").exists()
    assert "rest 30 min" in out  # the README's rest logs as a rest
    code = _blocks(README.read_text(encoding="utf-8"), "python")[0]
    ns: dict = {}
    exec(compile(code, "README.md", "exec"), ns)  # noqa: S102  (the README's own example)
    assert np.isfinite(ns["X"]).all()
