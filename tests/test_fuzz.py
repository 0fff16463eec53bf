"""Seeded fuzz of the CLI: hostile cards, schedules, scenarios, controllers, tables, images, flags,
campaign commands and databases, damaged files of an interrupted trial, documents nested too deep,
special files (FIFOs, devices), calibrate histories naming paths, unbounded work, errors quoting
newlines or long text, and crafted campaign databases.

Each example is one case of tests/fuzzlib.py run in-process through ``bmctl.cli.main``: it must
exit 0 with every output within physical bounds, or exit 2 with exactly one stderr line naming
the file, flag or field -- never a traceback, a hang (a per-case alarm) or an output outside
physical bounds. Hypothesis draws the case seeds, derandomized, so every run tries the same
cases; benchmarks/fuzz.py runs thousands of them (docs/reliability.md).
"""

from __future__ import annotations

import os
import signal
import tempfile
from contextlib import contextmanager
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from bmctl.cli import main

from . import fuzzlib

#: per-case limits: CPU seconds (a spinning command; robust to a busy machine) and wall seconds
#: (a command blocked on a pipe or a lock uses no CPU)
CASE_CPU_S = 30
CASE_WALL_S = 600


class Hang(BaseException):
    """The per-case alarm rang: the command did not finish in time."""


@contextmanager
def _limit(cpu_s: float, wall_s: int):
    def ring(signum, frame):
        raise Hang(f"no answer within {cpu_s} CPU s or {wall_s} s")

    old = signal.signal(signal.SIGALRM, ring), signal.signal(signal.SIGPROF, ring)
    signal.setitimer(signal.ITIMER_PROF, cpu_s)
    signal.alarm(wall_s)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_PROF, 0)
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old[0])
        signal.signal(signal.SIGPROF, old[1])


@contextmanager
def _env(extra: dict[str, str]):
    old = {k: os.environ.get(k) for k in extra}
    os.environ.update(extra)
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def run_case(case: fuzzlib.Case, capsys) -> tuple[str, str]:
    """Run one case in-process; returns (outcome, detail)."""
    capsys.readouterr()
    with tempfile.TemporaryDirectory(prefix="bmctl-fuzz-") as tmp:
        folder = Path(tmp)
        case.write(folder)
        try:
            with _env(case.env), _limit(CASE_CPU_S, CASE_WALL_S):
                for argv in case.commands(folder):
                    rc = main(argv)
                    if rc != 0:
                        break
        except Hang:
            rc = None
        except Exception as exc:  # anything escaping main is a traceback to the user
            cap = capsys.readouterr()
            return "traceback", f"{type(exc).__name__}: {exc} ({cap.err.strip()[-200:]})"
        cap = capsys.readouterr()
        return fuzzlib.classify(case, rc, cap.out, cap.err, folder / "out")


def _check(kind: str, seed: int, capsys) -> None:
    case = fuzzlib.make_case(kind, seed)
    outcome, detail = run_case(case, capsys)
    assert outcome in ("clean", "accepted-ok"), f"{kind}#{seed} {case.label}: {outcome}: {detail}"


FUZZ = dict(derandomize=True, deadline=None, database=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                                   HealthCheck.too_slow])
SEEDS = st.integers(0, 10**6)


@pytest.mark.slow
@settings(max_examples=14, **FUZZ)
@given(seed=SEEDS)
def test_fuzz_cards(seed, capsys, monkeypatch):
    monkeypatch.chdir(fuzzlib.ROOT)
    _check("card", seed, capsys)


@settings(max_examples=6, **FUZZ)
@given(seed=SEEDS)
def test_fuzz_schedules(seed, capsys, monkeypatch):
    monkeypatch.chdir(fuzzlib.ROOT)
    _check("schedule", seed, capsys)


@pytest.mark.slow
@settings(max_examples=6, **FUZZ)
@given(seed=SEEDS)
def test_fuzz_scenarios(seed, capsys, monkeypatch):
    monkeypatch.chdir(fuzzlib.ROOT)
    _check("scenario", seed, capsys)


@pytest.mark.slow
@settings(max_examples=6, **FUZZ)
@given(seed=SEEDS)
def test_fuzz_controllers(seed, capsys, monkeypatch):
    monkeypatch.chdir(fuzzlib.ROOT)
    _check("controller", seed, capsys)


@pytest.mark.slow
@settings(max_examples=8, **FUZZ)
@given(seed=SEEDS)
def test_fuzz_particle_tables(seed, capsys, monkeypatch):
    monkeypatch.chdir(fuzzlib.ROOT)
    _check("table", seed, capsys)


@pytest.mark.slow
@settings(max_examples=8, **FUZZ)
@given(seed=SEEDS)
def test_fuzz_images(seed, capsys, monkeypatch):
    monkeypatch.chdir(fuzzlib.ROOT)
    _check("image", seed, capsys)


@pytest.mark.slow
@settings(max_examples=12, **FUZZ)
@given(seed=SEEDS)
def test_fuzz_flags(seed, capsys, monkeypatch):
    monkeypatch.chdir(fuzzlib.ROOT)
    _check("flags", seed, capsys)


@pytest.mark.slow
@settings(max_examples=5, **FUZZ)
@given(seed=SEEDS)
def test_fuzz_campaigns(seed, capsys, monkeypatch):
    monkeypatch.chdir(fuzzlib.ROOT)
    _check("campaign", seed, capsys)


@pytest.mark.slow
@settings(max_examples=5, **FUZZ)
@given(seed=SEEDS)
def test_fuzz_resume(seed, capsys, monkeypatch):
    monkeypatch.chdir(fuzzlib.ROOT)
    _check("resume", seed, capsys)


@settings(max_examples=6, **FUZZ)
@given(seed=SEEDS)
def test_fuzz_nesting(seed, capsys, monkeypatch):
    monkeypatch.chdir(fuzzlib.ROOT)
    _check("nesting", seed, capsys)


@settings(max_examples=6, **FUZZ)
@given(seed=SEEDS)
def test_fuzz_special_files(seed, capsys, monkeypatch):
    monkeypatch.chdir(fuzzlib.ROOT)
    _check("special", seed, capsys)


@settings(max_examples=5, **FUZZ)
@given(seed=SEEDS)
def test_fuzz_histories(seed, capsys, monkeypatch):
    monkeypatch.chdir(fuzzlib.ROOT)
    _check("history", seed, capsys)


@settings(max_examples=6, **FUZZ)
@given(seed=SEEDS)
def test_fuzz_unbounded_work(seed, capsys, monkeypatch):
    monkeypatch.chdir(fuzzlib.ROOT)
    _check("work", seed, capsys)


@settings(max_examples=6, **FUZZ)
@given(seed=SEEDS)
def test_fuzz_one_line_errors(seed, capsys, monkeypatch):
    monkeypatch.chdir(fuzzlib.ROOT)
    _check("names", seed, capsys)


@settings(max_examples=6, **FUZZ)
@given(seed=SEEDS)
def test_fuzz_crafted_databases(seed, capsys, monkeypatch):
    monkeypatch.chdir(fuzzlib.ROOT)
    _check("database", seed, capsys)


# --- the checker itself must be able to fail ------------------------------------------------------

def test_checker_flags_outputs_outside_physical_bounds(tmp_path):
    (tmp_path / "moments.csv").write_text("t_h,s_mean_um,r_mean,temperature_c\n0,40,0.02,25\n1,0,1.0,2620\n", encoding="utf-8")
    bad = fuzzlib.check_outputs(tmp_path, fuzzlib.AL_MELTING_C)
    assert any("s_mean_um" in b for b in bad) and any("r_mean" in b for b in bad)
    assert any("temperature_c" in b for b in bad)
    (tmp_path / "moments.csv").write_text("t_h,s_mean_um,r_mean,temperature_c\n0,40,0.02,25\n1,35,0.1,60\n", encoding="utf-8")
    assert fuzzlib.check_outputs(tmp_path) == []


def test_checker_reads_designs_batch_end_row_as_no_action(tmp_path):
    """design's predicted.csv states no action over the batch end (empty cells on its last row); an empty
    action on any other row is nonsense (the checker called the stated one nonsense)."""
    head = "t_h,rpm,milling,t_peak_c,s_mean_um,s_std_um,r_mean,r_std,temperature_c,hardening,target_s_mean_um\n"
    (tmp_path / "predicted.csv").write_text(head + "0,0,0,25,40,4,0.02,0.02,25,0,30\n1,,,,40,4,0.02,0.02,25,0,30\n", encoding="utf-8")
    assert fuzzlib.check_outputs(tmp_path) == []
    (tmp_path / "predicted.csv").write_text(head + "0,,0,25,40,4,0.02,0.02,25,0,30\n1,,,,40,4,0.02,0.02,25,0,30\n", encoding="utf-8")
    assert fuzzlib.check_outputs(tmp_path) == ["predicted.csv: row 2: rpm = "]


def test_classify_sorts_outcomes(tmp_path):
    case = fuzzlib.Case("card", "x", [], names=["card.toml"])
    assert fuzzlib.classify(case, 2, "", "bmctl: error: card.toml: mill.rpm_max: bad\n", tmp_path)[0] == "clean"
    assert fuzzlib.classify(case, 2, "", "bmctl: error: something failed\n", tmp_path)[0] == "unnamed"
    assert fuzzlib.classify(case, 2, "", "bmctl: error: card.toml: a\nbmctl: error: b\n", tmp_path)[0] == "unnamed"
    assert fuzzlib.classify(case, 1, "", "Traceback (most recent call last):\n", tmp_path)[0] == "traceback"
    assert fuzzlib.classify(case, None, "", "", tmp_path)[0] == "hang"
    assert fuzzlib.classify(case, 0, "s mean nan um", "", tmp_path)[0] == "accepted-nonsense"
    assert fuzzlib.classify(case, 2, "", "bmctl: error: card.toml: " + "x" * 2000 + "\n", tmp_path)[0] == "unnamed"


def test_classify_flags_writes_outside_out_leaks_and_markup(tmp_path):
    case = fuzzlib.Case("history", "x", [], files={"h.toml": b"x"}, names=["h.toml"], sentinel="SENTINEL")
    case.write(tmp_path)
    (tmp_path / "out").mkdir()
    assert fuzzlib.classify(case, 2, "", "bmctl: error: h.toml: bad\n", tmp_path / "out")[0] == "clean"
    assert fuzzlib.classify(case, 2, "", "bmctl: error: h.toml: SENTINEL\n", tmp_path / "out")[0] == "unsafe"
    (tmp_path / "out" / "r.html").write_text('<p>ok</p><img src=x onerror="alert(1)">', encoding="utf-8")
    assert fuzzlib.classify(case, 0, "", "", tmp_path / "out")[0] == "unsafe"
    (tmp_path / "out" / "r.html").write_text("<p>&lt;script&gt;</p>", encoding="utf-8")
    assert fuzzlib.classify(case, 0, "", "", tmp_path / "out")[0] == "accepted-ok"
    (tmp_path / "X.png").write_bytes(b"")
    assert fuzzlib.classify(case, 0, "", "", tmp_path / "out")[0] == "unsafe"


def test_campaign_checker_flags_nonsense_in_the_database(tmp_path):
    import json
    import sqlite3

    con = sqlite3.connect(tmp_path / "campaign.sqlite")
    con.execute("CREATE TABLE meta (key, value)")
    con.execute("CREATE TABLE estimator_states (t_h, estimate)")
    con.execute("CREATE TABLE actions (t0_h, t1_h, rpm, milling)")
    con.execute("CREATE TABLE plans (rpm, milling, interval_h, advice)")
    con.execute("INSERT INTO meta VALUES ('hours', '2.0')")
    con.execute("INSERT INTO estimator_states VALUES (0.5, ?)", (json.dumps({"s_mean_um": 40.0, "r_mean": 1.5}),))
    con.execute("INSERT INTO actions VALUES (0.0, 0.5, 300.0, 1.0), (0.7, 1.0, 300.0, 1.0)")
    con.commit()
    con.close()
    bad = fuzzlib.check_campaign(tmp_path)
    assert any("r_mean" in b for b in bad) and any("0.7" in b for b in bad)


def test_resume_checker_compares_with_the_uninterrupted_run(tmp_path):
    ref = fuzzlib.reference_rows()
    (tmp_path / "summary.json").write_text('{"steps": 3}', encoding="utf-8")
    rows = [list(r) for r in ref]
    with open(tmp_path / "trajectory.csv", "w", encoding="utf-8") as fh:
        fh.write("".join(",".join(r) + "\n" for r in rows))
    assert fuzzlib.check_resumed(True)(tmp_path) == []
    rows[2][1] = "1.25"
    with open(tmp_path / "trajectory.csv", "w", encoding="utf-8") as fh:
        fh.write("".join(",".join(r) + "\n" for r in rows))
    assert fuzzlib.check_resumed(True)(tmp_path) != []
    assert fuzzlib.check_resumed(False)(tmp_path) == []
