"""``benchmarks/regenerate.py --only PATTERN --jobs N``: studies chosen by shell pattern (manual
ones only by name), the non-timing ones run N at a time with each one's output in its own log, the
timing ones after them, alone; a failure is named and a pattern that matches nothing refused."""

from __future__ import annotations

import sys

import pytest

from .conftest import load_benchmark


@pytest.fixture(scope="module")
def regen():
    return load_benchmark("regenerate")


def _studies(regen, tmp_path, fail: str = ""):
    """Fake studies that record their start and end times (and one that fails)."""
    def cmd(name, sleep):
        code = (f"import time, pathlib; p = pathlib.Path({str(tmp_path)!r}) / {name!r}; "
                f"p.write_text(repr(time.time())); time.sleep({sleep}); "
                f"p.write_text(p.read_text() + ' ' + repr(time.time())); print('hello from {name}'); "
                f"raise SystemExit({1 if name == fail else 0})")
        return f'"{sys.executable}" -c "{code}"'
    S = regen.Study
    return (S("fake_a", cmd("fake_a", 0.6), 0), S("fake_b", cmd("fake_b", 0.6), 0),
            S("fake_time", cmd("fake_time", 0.0), 0, timing=True), S("fake_manual", cmd("fake_manual", 0.0), 0,
                                                                       manual=True))


def _span(tmp_path, name):
    t0, t1 = map(float, (tmp_path / name).read_text().split())
    return t0, t1


def test_patterns_select_studies_in_order_without_the_manual_ones(regen, tmp_path):
    reg = _studies(regen, tmp_path)
    assert [s.name for s in regen.select(["fake_*"], reg)] == ["fake_a", "fake_b", "fake_time"]
    assert [s.name for s in regen.select(["fake_b", "fake_*", "fake_manual"], reg)] == [
        "fake_b", "fake_a", "fake_time", "fake_manual"]
    with pytest.raises(ValueError, match="nothing_like_this"):
        regen.select(["fake_a", "nothing_like_this*"], reg)


def test_jobs_run_the_quiet_studies_together_then_the_timing_ones_alone(regen, tmp_path, capsys):
    reg = _studies(regen, tmp_path)
    logs = tmp_path / "logs"
    assert regen.run_all(list(regen.select(["fake_*"], reg)), jobs=2, logs=logs) == []
    (a0, a1), (b0, b1), (t0, _) = (_span(tmp_path, n) for n in ("fake_a", "fake_b", "fake_time"))
    assert b0 < a1 and a0 < b1  # the two ran at the same time
    assert t0 >= max(a1, b1)  # the timing study after both
    assert (logs / "fake_a.log").read_text().strip() == "hello from fake_a"
    assert not (logs / "fake_time.log").exists()  # a timing study's output stays on the console


def test_a_failed_study_is_named_and_the_others_still_run(regen, tmp_path):
    reg = _studies(regen, tmp_path, fail="fake_a")
    assert regen.run_all(list(reg[:3]), jobs=2, logs=tmp_path / "logs") == ["fake_a"]
    assert (tmp_path / "fake_b").exists() and (tmp_path / "fake_time").exists()


def test_bad_arguments_are_refused_before_anything_runs(regen, capsys):
    assert regen.main(["--only", "no_such_study*"]) == 2
    assert "--only: unknown study no_such_study*" in capsys.readouterr().err
    assert regen.main(["--jobs", "0", "--only", "model_facts"]) == 2
    assert "--jobs: must be >= 1 (got 0)" in capsys.readouterr().err
