"""``benchmarks/hidden_mills.py --mills``: hidden mills of a user's own from a TOML file."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import pytest

from bmctl.errors import InputError
from tests.conftest import load_benchmark

ROOT = Path(__file__).resolve().parents[1]
ROW = ('name = "X"\ngamma_mult = 1.2\ndelta_mult = 0.8\nfield = "mill.ball_count"\nvalue = 9\nhours = 6.0\n'
       'rpm_ref = 300.0\n')


def _file(tmp_path, text: str) -> Path:
    p = tmp_path / "mills.toml"
    p.write_text(text, encoding="utf-8")
    return p


def test_shipped_mills_load_and_change_the_named_field_of_the_card():
    hm = load_benchmark("hidden_mills")
    cases = hm.load_mills(ROOT / "benchmarks" / "mills-unseen.toml")
    assert [c.name for c in cases] == list("MNOPQRS")
    known = {c.name for c in hm.CASES + hm.HELD_OUT}
    assert not known & {c.name for c in cases}  # none of them is a mill the controller was developed or held out on
    q = next(c for c in cases if c.name == "Q")
    card = hm.hidden_card(q)
    assert card.material.yield_stress_Pa == pytest.approx(95e6)
    lab = hm.hidden_card(hm.Case("lab", 1.0, 1.0, q.field, 78.7e6, q.hours, q.rpm_ref))
    assert card.stochastic.gamma_per_um2 == pytest.approx(1.6 * lab.stochastic.gamma_per_um2)
    assert card.stochastic.delta_per_um2 == pytest.approx(1.6 * lab.stochastic.delta_per_um2)


def test_feed_vial_mills_change_new_fields_or_earlier_ones_further():
    hm = load_benchmark("hidden_mills")
    earlier = hm.CASES + hm.HELD_OUT + hm.load_mills(ROOT / "benchmarks" / "mills-unseen.toml") \
        + hm.load_mills(ROOT / "benchmarks" / "mills-fields.toml")
    cases = hm.load_mills(ROOT / "benchmarks" / "mills-feed-vial.toml")
    assert [c.name for c in cases] == [f"W{i}" for i in range(1, 7)]
    new = {c.field for c in cases} - {c.field for c in earlier}
    assert new == {"thermal.heat_capacity_J_per_K", "initial.s_std_um", "thermal.ambient_C"}
    lab = hm.hidden_card(hm.Case("lab", 1.0, 1.0, "mill.ball_count", 10, 6.0, 300.0)).model_dump()
    for c in cases:  # a field an earlier mill changed is changed further from the card here
        sec, key = c.field.split(".")
        for e in (e for e in earlier if e.field == c.field):
            assert abs(math.log(c.value / lab[sec][key])) > abs(math.log(e.value / lab[sec][key])), (c.name, e.name)
    w2 = next(c for c in cases if c.name == "W2")
    assert hm.hidden_card(w2).initial.s_mean_um == pytest.approx(60.0)  # a feed unlike the card's 40 um


@pytest.mark.parametrize("text, where", [
    ("[[mill]]\n" + ROW.replace('"mill.ball_count"', '"mill.ball_cuont"'),
     "mill[0].field: not a field of the card"),
    ("[[mill]]\n" + ROW.replace("gamma_mult = 1.2", "gama_mult = 1.2"),
     "mill[0].gama_mult: unknown field (did you mean gamma_mult?)"),
    ("[[mill]]\n" + ROW.replace("rpm_ref = 300.0", "rpm_ref = 900.0"), "mill[0].rpm_ref:"),
    ("[[mill]]\n" + ROW + "[[mill]]\n" + ROW, "names must be unique (repeated: X)"),
    ("[[mill]]\n" + ROW.replace("value = 9", "value = 9.5"), "mill[0] (X): the hidden card: mill.ball_count:"),
    ("[[mill]]\n" + ROW.replace("value = 9", "value = -0.01").replace("ball_count", "ball_diameter_m"),
     "mill[0] (X): the hidden card: mill.ball_diameter_m:"),
    ("mill = []\n", "mill:"),
    ("[[mill]\n", "malformed TOML"),
])
def test_a_bad_mills_file_names_the_file_and_the_field(tmp_path, text, where):
    p = _file(tmp_path, text)
    with pytest.raises(InputError) as e:
        load_benchmark("hidden_mills").load_mills(p)
    msg = str(e.value)
    assert msg.startswith(str(p)) and where in msg and "\n" not in msg


def test_the_benchmark_refuses_a_bad_mills_file_with_exit_2_and_one_line(tmp_path):
    p = _file(tmp_path, "[[mill]]\n" + ROW.replace("hours = 6.0", "hours = -1"))
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "hidden_mills.py"), "--mills", str(p),
                        "--no-results", "--out", str(out)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "mill[0].hours" in lines[0] and "Traceback" not in r.stderr
    assert not out.exists()  # nothing written


def test_unknown_case_of_a_mills_file_is_refused(tmp_path):
    p = _file(tmp_path, "[[mill]]\n" + ROW)
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "hidden_mills.py"), "--mills", str(p),
                        "--cases", "A", "--no-results", "--out", str(tmp_path / "o")],
                       capture_output=True, text=True, timeout=120)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "Traceback" not in r.stderr
    assert "--cases: unknown mill(s) A (known: X)" in lines[0]
    assert not (tmp_path / "o").exists()


def test_a_bad_controller_file_is_refused_with_exit_2_and_one_line(tmp_path):
    bad = tmp_path / "ctrl.toml"
    bad.write_text((ROOT / "benchmarks" / "mpc-narrow-pool.toml").read_text(encoding="utf-8").replace("pool_band = 0.015",
                                                                                       "pool_band = 3"), encoding="utf-8")
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "hidden_mills.py"), "--controller", str(bad),
                        "--cases", "A", "--no-results", "--out", str(out)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "plan.pool_band" in lines[0] and str(bad) in lines[0] and "Traceback" not in r.stderr
    assert not out.exists()


@pytest.mark.parametrize("variant, key, differs", [
    ("mpc-narrow-pool.toml", "pool_band", lambda v, d: v < d),  # a narrower pool
    ("mpc-nudge.toml", "nudge", lambda v, d: v and not d),  # nudges on
    ("mpc-onset8.toml", "onset_substeps", lambda v, d: v == 8 and d is None),  # bursts at 8 substeps
])
def test_each_benchmark_variant_differs_from_the_default_in_one_plan_field(variant, key, differs):
    from bmctl.control.config import load_controller

    a = load_controller(ROOT / "benchmarks" / variant).model_dump()
    b = load_controller(ROOT / "controllers" / "mpc-default.toml").model_dump()
    assert differs(a["plan"].pop(key), b["plan"].pop(key))
    for d in (a, b):
        d.pop("name"), d.pop("description", None)
    assert a == b


def test_a_hidden_mill_slower_than_the_sweep_is_refused_before_anything_runs(tmp_path):
    """A top speed under the 500 rpm the sweep and the controller may ask for: one line naming the
    file, the mill and mill.rpm_max, exit 2, nothing written (the operator could not run the advice)."""
    row = ROW.replace('"mill.ball_count"', '"mill.rpm_max"').replace("value = 9", "value = 400.0")
    p = _file(tmp_path, "[[mill]]\n" + row)
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "hidden_mills.py"), "--mills", str(p),
                        "--no-results", "--out", str(out)], capture_output=True, text=True, timeout=120)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "Traceback" not in r.stderr
    assert str(p) in lines[0] and "(X)" in lines[0] and "mill.rpm_max" in lines[0]
    assert not out.exists()


def test_each_mill_name_seeds_its_own_campaign():
    """Names of several letters are allowed by the mills file: their campaigns are seeded apart, and a
    one-letter name keeps the seed sequence of the shipped mills."""
    hm = load_benchmark("hidden_mills")
    draws = {n: hm.case_seeds(0, n).generate_state(2).tolist() for n in ("C", "T1", "T2", "T12")}
    assert len({tuple(v) for v in draws.values()}) == 4
    import numpy as np

    assert draws["C"] == np.random.SeedSequence([0, 67]).generate_state(2).tolist()


def test_a_hidden_mill_without_a_target_under_the_ceiling_stops_before_any_campaign(tmp_path):
    """A vial that starts at 79 °C: no constant speed of the sweep stays 3 °C under the 80 °C ceiling,
    so no target can be chosen: one line naming the file and the mill, exit 2, no campaign run."""
    row = (ROW.replace('"mill.ball_count"', '"thermal.ambient_C"').replace("value = 9", "value = 79.0")
           .replace("hours = 6.0", "hours = 0.5"))
    p = _file(tmp_path, "[[mill]]\n" + row)
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "hidden_mills.py"), "--mills", str(p),
                        "--particles", "200", "--no-results", "--out", str(out)],
                       capture_output=True, text=True, timeout=300)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "Traceback" not in r.stderr
    assert str(p) in lines[0] and "mill X" in lines[0] and "no constant speed" in lines[0]
    assert not out.exists()  # the folder is made only once every target is found


@pytest.mark.parametrize("every", ["0.7", "0", "-1"])
def test_a_sampling_interval_off_the_advice_grid_is_refused(tmp_path, every):
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "hidden_mills.py"), "--sample-every-h", every,
                        "--no-results", "--out", str(out)], capture_output=True, text=True, timeout=120)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "--sample-every-h" in lines[0] and "Traceback" not in r.stderr
    assert not out.exists()


def test_a_card_without_moment_coefficients_is_refused_with_exit_2_and_one_line(tmp_path):
    card = tmp_path / "mine.toml"  # a copy of a shipped card without its <card>.moments.toml beside it
    card.write_text((ROOT / "models" / "alni-1to3-300rpm-hadjiafxenti.toml").read_text(encoding="utf-8"), encoding="utf-8")
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "hidden_mills.py"), "--card", str(card),
                        "--no-results", "--out", str(out)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and str(card) in lines[0] and "moment coefficients" in lines[0]
    assert "Traceback" not in r.stderr and not out.exists()


def test_mills_around_another_card_change_that_card():
    hm = load_benchmark("hidden_mills")
    other = ROOT / "models" / "alni-1to3-300rpm-hadjiafxenti.toml"
    cases = hm.load_mills(ROOT / "benchmarks" / "mills-1to3.toml", other)
    y4 = next(c for c in cases if c.name == "Y4")
    from bmctl.config import load_card, with_factors

    base = with_factors(load_card(other), y4.gamma, y4.delta)
    card = hm.hidden_card(y4, other)
    assert card.initial.s_mean_um == pytest.approx(50.0)
    assert card.stochastic.gamma_per_um2 == pytest.approx(base.stochastic.gamma_per_um2)
    assert card.material.model_dump() == base.material.model_dump()  # the 1:3 powder, not the lab card's
    lab = load_card(hm.CARD)
    assert card.material.model_dump() != lab.material.model_dump()


ALSO = '[mill.also]\n"thermal.ambient_C" = 20.0\n"mill.ball_diameter_m" = 0.012\n'


def test_a_mill_may_change_more_fields_and_its_hidden_card_changes_each():
    """``[mill.also]``: every listed field is set on the hidden card (a ball's mass follows its new
    size), the mill's ``field`` first; the docs table lists each changed field."""
    import tempfile

    hm = load_benchmark("hidden_mills")
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "mills.toml"
        p.write_text("[[mill]]\n" + ROW + ALSO, encoding="utf-8")
        (case,) = hm.load_mills(p)
    assert case.changes() == (("mill.ball_count", 9), ("thermal.ambient_C", 20.0), ("mill.ball_diameter_m", 0.012))
    card = hm.hidden_card(case)
    lab = hm.hidden_card(hm.Case("lab", 1.0, 1.0, "mill.ball_count", 10, 6.0, 300.0))
    assert (card.mill.ball_count, card.thermal.ambient_C, card.mill.ball_diameter_m) == (9, 20.0, 0.012)
    assert card.material.impactor_mass_kg == pytest.approx(lab.material.impactor_mass_kg * 1.2 ** 3)
    row = {"case": "X", "gamma_mult": 1.2, "delta_mult": 0.8, "field": "mill.ball_count", "value": 9,
           "also": dict(case.also), "hours": 6.0, "plain_schedule": "300 rpm continuous"}
    keys = ("target_s_mean_um", "error_pct", "peak_c", "idle_needed_h", "longest_idle_needed_h", "plain_error_pct")
    summary = {k: 1.0 for k in ("median_error_pct", "worst_error_pct", "max_over_ceiling_c", "longest_idle_needed_h",
                                "plain_median_error_pct", "plain_worst_error_pct")}
    table = hm.table([{**row, **{k: 1.0 for k in keys}}], {**summary, "campaign_beats_plain": 1}, "x")
    assert "| ball_count = 9; ambient_C = 20; ball_diameter_m = <!--in-->0.012<!--/in--> |" in table


@pytest.mark.parametrize("also, where", [
    ('[mill.also]\n"thermal.ambiant_C" = 20.0\n', "mill[0].also: not a field of the card"),
    ('[mill.also]\n"thermal.ambient_C" = "warm"\n', "mill[0].also: thermal.ambient_C: must be a finite number"),
    ('[mill.also]\n"mill.ball_count" = 12\n', "mill[0]: also: mill.ball_count is the mill's field already"),
    ('[mill.also]\n"simulation.particles" = 200\n', "mill[0].also: the hidden plant's particles are --particles"),
    ('[mill.also]\nambient = 3\n', 'mill[0].also: keys are card fields as "section.key"'),
    ('[mill.also]\n"mill.ball_diameter_m" = -0.01\n', "mill[0] (X): the hidden card: mill.ball_diameter_m:"),
])
def test_a_bad_also_table_names_the_file_and_the_field(tmp_path, also, where):
    p = _file(tmp_path, "[[mill]]\n" + ROW + also)
    with pytest.raises(InputError) as e:
        load_benchmark("hidden_mills").load_mills(p)
    msg = str(e.value)
    assert msg.startswith(str(p)) and where in msg and "\n" not in msg
