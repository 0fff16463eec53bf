"""``benchmarks/hidden_mills_floor.py``: a run's final error against the estimate's error at its last advice."""

from __future__ import annotations

import pytest

from tests.conftest import load_benchmark


def _case(name, final_pct, est_last_um, plant_last_um, est_1h_um=50.0, plant_1h_um=50.0):
    steps = [{"t_h": 0.0, "estimate_s_mean_um": 40.0, "plant_s_mean_um": 40.0},
             {"t_h": 1.0, "estimate_s_mean_um": est_1h_um, "plant_s_mean_um": plant_1h_um},
             {"t_h": 1.5, "estimate_s_mean_um": est_last_um, "plant_s_mean_um": plant_last_um}]
    return {"case": name, "error_pct": final_pct, "steps": steps}


def test_a_plan_that_steers_its_estimate_exactly_leaves_minus_the_estimates_error():
    """Each run ends off by minus its estimate's error at the last advice: correlation 1, nothing left;
    the hourly samples (not t = 0, not the half hour) give the sample RMS."""
    fl = load_benchmark("hidden_mills_floor")
    res = {"cases": [_case("A", -2.0, 51.0, 50.0), _case("B", 4.0, 48.0, 50.0),
                     _case("C", 1.0, 49.5, 50.0, 55.0, 50.0)]}
    rows = fl.run_rows(res, "f")
    assert [r["estimate_error_last_advice_pct"] for r in rows] == pytest.approx([2.0, -4.0, -1.0])
    s = fl.summary(rows)
    assert s["corr_final_vs_minus_estimate"] == pytest.approx(1.0)
    assert s["left_rms_pct"] == pytest.approx(0.0, abs=1e-12)
    assert s["samples"] == 3 and s["estimate_at_samples_rms_pct"] == pytest.approx((100 / 3) ** 0.5)
    assert s["over_5pct"] == []
    # the half hour after the sample: predicted, no sample of its own (t = 1.5 h, the last advice)
    assert s["between_samples"] == 3 and s["estimate_between_samples_rms_pct"] == pytest.approx(7 ** 0.5)
    assert s["run_mean_between_samples_rms_pct"] == pytest.approx(7 ** 0.5)
    assert s["last_advice_between_samples"] == 3
    res["cases"].append(_case("D", 6.0, 50.0, 50.0))
    assert fl.summary(fl.run_rows(res, "f"))["over_5pct"] == ["f:D"]


def test_figure_draws_both_sample_sizes_from_the_results_file(tmp_path):
    fl = load_benchmark("hidden_mills_floor")
    runs = [{"file": "f", "case": c, "final_error_pct": e, "estimate_error_last_advice_pct": -e + 0.5}
            for c, e in zip("ABCD", (1.0, -2.0, 3.0, 0.5))]
    s = fl.summary([dict(r, estimate_errors_at_samples_pct=[1.0], estimate_errors_between_samples_pct=[2.0],
                         last_advice_t_h=11.5) for r in runs])
    rec = {"summary": s, "runs": runs, "samples1000": {"summary": s, "runs": runs}}
    out = fl.figure(rec, tmp_path / "floor.png")
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000
    assert [p.name for p in tmp_path.iterdir()] == ["floor.png"]


def test_idle_stretches_are_rests_begun_off_the_target_to_the_next_burst():
    """A rest begun 4 % off the target lasts to the next milling advice (1.5 h) and is over the bar; a rest
    begun within 2 % is not counted; the last rest runs to the batch end."""
    fl = load_benchmark("hidden_mills_floor")
    plant = [40.0, 52.0, 52.0, 52.0, 52.0, 51.0, 51.0, 53.0]
    est = [40.0, 50.5, 50.0, 50.0, 50.0, 50.5, 50.5, 52.0]
    mill = [30, 0, 0, 0, 10, 0, 0, 0]
    steps = [{"t_h": 0.5 * k, "mill_min": m, "plant_s_mean_um": p, "estimate_s_mean_um": e}
             for k, (m, p, e) in enumerate(zip(mill, plant, est))]
    case = {"case": "A", "error_pct": 6.0, "target_s_mean_um": 50.0, "hours": 4.0, "steps": steps}
    got = fl.idle_stretches(case)
    assert [(r["t_h"], r["hours"]) for r in got] == [(0.5, 1.5), (3.5, 0.5)]
    assert got[0]["plant_error_pct"] == pytest.approx(4.0) and got[0]["estimate_error_pct"] == pytest.approx(1.0)
    other = dict(case, case="B", error_pct=-1.0, steps=steps[:-1] + [dict(steps[-1], estimate_s_mean_um=51.0)])
    s = fl.summary(fl.run_rows({"cases": [case, other]}, "f"))
    assert s["idle_over_bar"] == 2 and s["idle_over_bar_estimate_within_tol"] == 2
    assert s["idle_over_bar_plant_error_abs_max_pct"] == pytest.approx(4.0)
