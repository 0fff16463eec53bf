"""A schedule file reads the same wherever it is read (milling shares kept, the same limits), toml()
writes what load() reads back, and the schedule constructors refuse what a schedule file refuses."""

import math
import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from bmctl.calibrate.history import load_history
from bmctl.config import load_card, load_schedule
from bmctl.errors import InputError
from bmctl.schedule import Schedule, as_schedule

from .conftest import ROOT, card_path

SAMPLES = ROOT / "examples" / "samples"
LAB = card_path("alni-1to1-300rpm-lab")
TWO_SAMPLES = ('\n[[sample]]\nt_h = 0.5\ntable = "samples/lab-300rpm-0p5h.csv"\n'
               '[[sample]]\nt_h = 1\ntable = "samples/lab-300rpm-1h.csv"\n')


def _history(tmp_path: Path, schedule_text: str, head: str = 'schedule = "sched.toml"\n') -> Path:
    (tmp_path / "samples").mkdir(exist_ok=True)
    for name in ("lab-300rpm-0p5h.csv", "lab-300rpm-1h.csv"):
        shutil.copy(SAMPLES / name, tmp_path / "samples" / name)
    (tmp_path / "sched.toml").write_text(schedule_text, encoding="utf-8")
    p = tmp_path / "h.toml"
    p.write_text('name = "a"\n' + head + TWO_SAMPLES, encoding="utf-8")
    return p


# --- one reader of schedule files --------------------------------------------------------------------
def test_a_history_keeps_the_milling_shares_of_its_schedule_file(tmp_path):
    """A schedule file with `milling` (as toml() writes it) was refused: `segment[0].milling: unknown field`."""
    p = _history(tmp_path, Schedule.from_pairs([(1.0, 300.0, 0.75)], name="s").toml())
    assert load_history(p).segments == [(1.0, 300.0, 0.75)]


@pytest.mark.parametrize("text, needle", [
    ("[[segment]]\nhours = 1\nrpm = 300\nmilling = 0.00001\n", "segment[0].milling: mills 0.036 s"),
    ("[[segment]]\nhours = 600\nrpm = 300\n[[segment]]\nhours = 600\nrpm = 0\n", "segment: the segments' hours add up"),
])
def test_a_history_holds_its_schedule_file_to_a_schedule_files_limits(tmp_path, text, needle):
    p = _history(tmp_path, text)
    with pytest.raises(InputError) as e:
        load_history(p)
    msg = str(e.value)
    assert msg.startswith(str(tmp_path / "sched.toml")) and needle in msg and "\n" not in msg, msg


def test_inline_history_segments_are_held_to_the_total_of_a_batch(tmp_path):
    inline = "[[segment]]\nhours = 600\nrpm = 300\n[[segment]]\nhours = 600\nrpm = 0\n"
    p = _history(tmp_path, "", head=inline)
    with pytest.raises(InputError, match=r"h\.toml: segment: the segments' hours add up to 1200 h"):
        load_history(p)


def test_config_load_schedule_reads_milling_and_as_schedule_keeps_it(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text(Schedule.from_pairs([(1.0, 300.0, 0.75), (0.5, 0.0)], name="s").toml(), encoding="utf-8")
    cfg = load_schedule(p)
    assert [s.milling for s in cfg.segment] == [0.75, 1.0]
    assert as_schedule(cfg) == Schedule.load(p)
    assert as_schedule(cfg).pairs() == [(0.75, 300.0), (0.25, 0.0), (0.5, 0.0)]


# --- toml() writes what load() reads ------------------------------------------------------------------
ODD = Schedule.from_pairs([(7 / 60, 1234.56789), (1 / 3, 300.0, 1 / 3), (0.5, 0.0),
                           (2.0, 1999.9999999, 0.123456789012)], name='lab "A" \\ run 2')


@pytest.mark.parametrize("name", ["", ODD.name])
def test_toml_reads_back_exactly(tmp_path, name):
    """rpm was written with %g (1234.56789 -> 1234.57), hours to 10 digits and the name unescaped."""
    sched = Schedule(ODD.segments, name)
    p = tmp_path / "s.toml"
    p.write_text(sched.toml(), encoding="utf-8")
    assert Schedule.load(p) == sched


def test_toml_keeps_the_short_form_of_ordinary_values():
    text = Schedule.from_pairs([(0.5, 300.0), (1.0, 0.0), (12.0, 450.5, 0.75)], name="ramp").toml()
    assert text == ('name = "ramp"\n\n[[segment]]\nhours = 0.5   # 30 min\nrpm = 300\n\n'
                    "[[segment]]\nhours = 1   # 60 min\nrpm = 0\n\n"
                    "[[segment]]\nhours = 12   # 720 min\nrpm = 450.5\nmilling = 0.75\n")


def test_a_designed_schedule_reads_back_exactly(tmp_path):
    """`bmctl design` wrote its own segments (rpm %g, hours to 10 digits, the card name unquoted)."""
    from bmctl.control.design import Design, schedule_toml

    segs = [(7 / 60, 1234.56789), (0.5, 0.0), (1 / 3, 300.0)]
    result = SimpleNamespace(method="search", status="ok", solve_s=0.1, outputs={"s_mean_um": 40.0}, error=0.01)
    d = Design(card_name='my "lab"', controller_name="mpc", target={"s_mean_um": 40.0}, hours=1.0, ceiling_c=60.0,
               U=np.zeros((3, 2)), X=np.zeros((4, 6)), t_peak_c=np.zeros(3), segments=segs, result=result,
               reach=None)
    p = tmp_path / "schedule.toml"
    p.write_text(schedule_toml(d), encoding="utf-8")
    s = Schedule.load(p)
    assert s.name == 'design-my "lab"' and s.pairs() == segs


def test_a_written_history_reads_back_with_its_name(tmp_path):
    from bmctl.calibrate.history import History, MeasuredSample
    from bmctl.calibrate.synthetic import write_history

    rng = np.random.default_rng(0)
    smp = MeasuredSample(1.0, rng.uniform(20, 60, 30), rng.uniform(0, 0.3, 30), "x")
    p = write_history(History('run "7"', "", [(2.0, 300.0, 0.75)], [smp]), tmp_path)
    h = load_history(p)
    assert h.name == 'run "7"' and h.segments == [(2.0, 300.0, 0.75)]


# --- the constructors refuse what a schedule file refuses --------------------------------------------
@pytest.mark.parametrize("hours", [-5.0, 0.0, 2000.0, math.nan])
def test_from_card_refuses_hours_outside_a_batch_as_card_schedule_does(hours):
    """hours=-5 gave an empty schedule, hours=2000 6000 segments past the 1000-h limit."""
    from bmctl.config import card_schedule

    card = load_card(card_path("alni-1to1-400rpm-fan"))
    with pytest.raises(InputError) as want:
        card_schedule(card, hours)
    with pytest.raises(InputError) as got:
        Schedule.from_card(card, hours=hours)
    assert str(got.value) == str(want.value) and "outside [1 s, 1000 h]" in str(got.value)


@pytest.mark.parametrize("rpm", [-1.0, math.nan, 5000.0])
def test_from_card_refuses_a_speed_outside_the_range(rpm):
    with pytest.raises(InputError, match=r"^rpm: "):
        Schedule.from_card(load_card(LAB), hours=1.0, rpm=rpm)


def test_from_card_is_card_schedule():
    from bmctl.config import card_schedule

    card = load_card(card_path("alni-1to1-400rpm-fan"))
    for hours in (None, 1.0, 1.0001, 7.3):
        assert Schedule.from_card(card, hours).pairs() == card_schedule(card, hours)


@pytest.mark.parametrize("pairs, needle", [
    ([(-1.0, 300.0)], "segment[0].hours: -1 h is outside [0, 1000 h]"),
    ([(1.0, 300.0), (1.0, math.nan)], "segment[1].rpm: nan is outside [0, 2000] rpm"),
    ([(1.0, 300.0, 2.0)], "segment[0].milling: 2 is outside [0, 1]"),
    ([(1.0, 300.0, -0.5)], "segment[0].milling: -0.5 is outside [0, 1]"),
    ([(math.inf, 300.0)], "segment[0].hours: inf h"),
    ([(600.0, 300.0), (600.0, 0.0)], "segment: the segments' hours add up to 1200 h"),
    ([(1.0,)], "segment[0]: give (hours, rpm) or (hours, rpm, milling), not 1 values"),
])
def test_from_pairs_refuses_what_a_schedule_file_refuses(pairs, needle):
    with pytest.raises(InputError) as e:
        Schedule.from_pairs(pairs)
    assert str(e.value).startswith(needle), str(e.value)


def test_from_pairs_keeps_short_pieces_of_a_cut_recipe_or_a_plan():
    s = Schedule.from_pairs([(1e-4, 300.0), (0.5, 300.0, 0.9999), (0.0, 0.0)])
    assert s.pairs()[0] == (1e-4, 300.0) and s.hours == pytest.approx(0.5001)


# --- grid keeps the time -----------------------------------------------------------------------------
def test_grid_of_whole_intervals_is_one_row_per_interval():
    s = Schedule.from_pairs([(1.0, 300.0, 0.5), (0.5, 0.0), (1.5, 450.0)])
    assert s.grid(0.5) == [(300.0, 0.5)] * 2 + [(0.0, 1.0)] + [(450.0, 1.0)] * 3


def test_grid_rounds_the_total_not_each_segment():
    """Five 0.2-h segments on a 0.5-h grid gave no interval at all (each rounded to 0)."""
    assert len(Schedule.from_pairs([(0.2, 300.0)] * 5).grid(0.5)) == 2
    rng = np.random.default_rng(3)
    for _ in range(20):
        hours = rng.uniform(0.01, 0.7, rng.integers(1, 12))
        n = len(Schedule.from_pairs([(h, 300.0) for h in hours]).grid(0.25))
        assert abs(n * 0.25 - hours.sum()) <= 0.125 + 1e-12


# --- the ceiling count is of sub-steps ----------------------------------------------------------------
def test_the_ceiling_count_is_described_as_sub_steps_not_crossings():
    from bmctl.loop import LoopConfig

    doc = " ".join(LoopConfig.__doc__.split())
    text = " ".join((ROOT / "docs" / "loop.md").read_text(encoding="utf-8").split())
    for t in (doc, text):
        assert "crossings are counted" not in t and "sub-steps" in t and "that end above" in t
