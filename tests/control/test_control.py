"""Controllers: MPC on the moment model (closed loop), fallback, constraints, on/off handling,
baselines, configs and the `bmctl design` command."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bmctl.cli import main
from bmctl.config import load_schedule
from bmctl.control import applied_input, make_controller, peak_temperature
from bmctl.control.base import Reference, applied_input_guarded, schedule_segments
from bmctl.control.config import load_controller, parse_target, validate_controller
from bmctl.errors import InputError
from bmctl.moments.model import make_moment_model

from ..conftest import ROOT

CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
CTRL = ROOT / "controllers"
DT = 0.5


@pytest.fixture(scope="module")
def model():
    return make_moment_model(CARD)


def mpc_cfg(**over):
    """A short-horizon MPC config (fast enough for tests)."""
    d = {"kind": "mpc", "interval_h": DT, "horizon": 4, "batch_hours": 2.0,
         "bounds": {"rpm_min": 100.0, "rpm_max": 500.0, "rpm_step_max": 100.0}}
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(d.get(k), dict):
            d[k] = {**d[k], **v}
        else:
            d[k] = v
    return validate_controller(d, "test")


def closed_loop(model, ctrl, hours, x=None):
    """Run a controller against the moment model itself; returns (final x, plans, applied inputs, states)."""
    x = model.x0() if x is None else np.asarray(x, dtype=float)
    u, plans, U, X = None, [], [], [x]
    for k in range(int(round(hours / ctrl.interval_h))):
        plan = ctrl.plan(x, k * ctrl.interval_h, None, u)
        u = plan.u_apply
        plans.append(plan)
        U.append(u)
        x = model.step(x, u, ctrl.interval_h)
        X.append(x)
    return x, plans, np.array(U), np.array(X)


def check_rpm_limits(U, lo, hi, step):
    milling = U[:, 1] > 0
    assert np.all((U[milling, 0] >= lo - 1e-6) & (U[milling, 0] <= hi + 1e-6))
    rpm = U[milling, 0]
    assert np.all(np.abs(np.diff(rpm)) <= step + 1e-6)


# --- MPC closed loop on the moment model -----------------------------------------------------


@pytest.fixture(scope="module")
def reach(model):
    """Target = the moment model's own state after 2 h at 350 rpm, 80 % milling (so reachable)."""
    Xs = model.simulate(model.x0(), [[350.0, 0.8]] * 4, DT)
    target = {"s_mean_um": float(Xs[-1, 0]), "r_mean": float(Xs[-1, 2])}
    ctrl = make_controller(mpc_cfg(temperature={"ceiling_c": 90.0}), model, target)
    return target, closed_loop(model, ctrl, 2.0)


@pytest.mark.slow
def test_mpc_reaches_a_reachable_target(reach):
    target, (x, plans, U, X) = reach
    assert all(p.status.fallback == "none" for p in plans), [p.status.line() for p in plans]
    assert x[0] == pytest.approx(target["s_mean_um"], rel=0.02)
    assert x[2] == pytest.approx(target["r_mean"], rel=0.05)


@pytest.mark.slow
def test_mpc_bounds_rate_limits_and_minutes(reach):
    _, (x, plans, U, X) = reach
    check_rpm_limits(U, 100.0, 500.0, 100.0)
    assert np.all((U[:, 1] >= 0) & (U[:, 1] <= 1))
    minutes = U[:, 1] * DT * 60
    assert np.allclose(minutes, np.round(minutes))
    for p in plans:  # each plan obeys the rate limit between its own intervals, and bounds
        on = p.u[:, 1] > 1e-3
        assert np.all(np.abs(np.diff(p.u[:, 0])) <= 100.0 + 1e-3)
        assert np.all((p.u[on, 0] >= 100 - 1e-3) & (p.u[on, 0] <= 500 + 1e-3))
        assert p.x.shape == (p.u.shape[0] + 1, 6) and p.t_peak_c.shape == (p.u.shape[0],)


@pytest.mark.slow
def test_controllers_with_the_same_build_share_the_nlp_and_solvers(model):
    """A second controller built from the same model and configuration reuses the first one's NLP
    (and so its solvers); another horizon or a D-value target builds its own."""
    a = make_controller(mpc_cfg(horizon=2), model, {"s_mean_um": 40.0})
    b = make_controller(mpc_cfg(horizon=2), model, {"s_mean_um": 30.0})
    c = make_controller(mpc_cfg(horizon=3), model, {"s_mean_um": 40.0})
    d = make_controller(mpc_cfg(horizon=2), model, {"d50_um": 40.0})
    for ctrl in (a, b, c, d):
        ctrl._build()
    assert a._nlp is b._nlp and a._built is b._built
    assert c._nlp is not a._nlp and d._nlp is not a._nlp
    assert a._build_key() == b._build_key() != c._build_key()


def test_expanded_warm_solver_gives_the_same_plans(model):
    # expand = "warm" only changes how casadi evaluates the NLP (SX instead of MX), not the problem
    Xs = model.simulate(model.x0(), [[350.0, 0.8]] * 3, DT)
    target = {"s_mean_um": float(Xs[-1, 0])}
    runs = []
    for expand in ("none", "warm"):
        cfg = mpc_cfg(horizon=3, batch_hours=1.5, solver={"hessian": "limited-memory", "expand": expand})
        ctrl = make_controller(cfg, model, target)
        runs.append(closed_loop(model, ctrl, 1.5))
        kinds = {k: s.oracle().is_a("SXFunction") for k, s in ctrl._solvers.items()}
        assert kinds == {("cold", "exact"): False, ("warm", "limited-memory"): expand == "warm"}
    (xa, pa, Ua, _), (xb, pb, Ub, _) = runs
    assert all(p.status.fallback == "none" for p in pa + pb)
    assert np.allclose(Ua, Ub, rtol=0.02, atol=1.0 / 60)  # applied rpm within 2 %, milling within a minute
    assert xb[0] == pytest.approx(xa[0], rel=0.005)


@pytest.mark.slow
def test_adaptive_gain_learns_a_slower_plant_and_reaches_the_target(model):
    # "plant" = the moment model with half its particle-moment changes per interval; the adaptive
    # MPC's gains must learn ~0.5 and its final error must be well below the plain MPC's
    Xs = model.simulate(model.x0(), [[350.0, 1.0]] * 4, DT)
    target = {"s_mean_um": float(Xs[-1, 0])}
    finals = {}
    for adaptive in (False, True):
        cfg = mpc_cfg(batch_hours=3.0, temperature={"ceiling_c": 200.0},
                      solver={"hessian": "limited-memory"}, adaptation={"mode": "gain" if adaptive else "none", "forgetting": 1.0})
        ctrl = make_controller(cfg, model, target)
        x, u = model.x0(), None
        for k in range(6):
            plan = ctrl.plan(x, k * DT, None, u)
            assert plan.status.fallback == "none", plan.status.line()
            u = plan.u_apply
            xn = model.step(x, u, DT)
            x = np.concatenate([x[:4] + 0.5 * (xn[:4] - x[:4]), xn[4:]])
        ctrl.plan(x, 3.0, None, u)  # the last call updates the gains too
        finals[adaptive] = abs(x[0] / target["s_mean_um"] - 1)
        if adaptive:
            assert np.all(np.abs(ctrl.gain - 0.5) < 0.1), ctrl.gain
        else:
            assert np.all(ctrl.gain == 1.0)
    assert finals[True] < 0.5 * finals[False], finals


@pytest.mark.slow
def test_offset_free_bias_reduces_the_error_of_a_mismatched_model(model):
    # "plant" = the moment model told gamma x1.5, delta x0.6 (about the mismatch that x1.3, x0.7
    # gave before p acted inside eqns 15 and 20); the controller's model has (1, 1). Like a trial, the controller sees the true state every 2nd interval (a
    # sample) and its model's prediction in between. The "bias" MPC must learn a positive
    # s_mean discrepancy and end at most half as far from the target as the plain MPC.
    p_true = np.array([1.5, 0.6])
    target = {"s_mean_um": 60.0}
    finals = {}
    for mode in ("none", "bias"):
        cfg = mpc_cfg(batch_hours=4.0, temperature={"ceiling_c": 200.0},
                      solver={"hessian": "limited-memory"}, adaptation={"mode": mode, "forgetting": 0.7})
        ctrl = make_controller(cfg, model, target)
        x_true, x_seen, u = model.x0(), model.x0(), None
        for k in range(8):
            plan = ctrl.plan(x_seen, k * DT, None, u)
            assert plan.status.fallback == "none", plan.status.line()
            u = plan.u_apply
            x_true = model.step(x_true, u, DT, p_true)
            x_seen = x_true.copy() if k % 2 == 1 else model.step(x_seen, u, DT)
        finals[mode] = abs(x_true[0] / target["s_mean_um"] - 1)
        if mode == "bias":
            assert ctrl.bias[0] > 1.0, ctrl.bias  # the plant grows more than the model predicts
        else:
            assert np.all(ctrl.bias == 0)
    assert finals["bias"] < 0.5 * finals["none"], finals


@pytest.mark.slow
def test_mpc_rate_limit_from_last_applied_rpm(model):
    Xs = model.simulate(model.x0(), [[480.0, 1.0]] * 2, DT)
    ctrl = make_controller(mpc_cfg(horizon=2, batch_hours=1.0, temperature={"ceiling_c": 200.0}), model,
                           {"s_mean_um": float(Xs[-1, 0])})
    plan = ctrl.plan(model.x0(), 0.0, None, u_prev=(150.0, 1.0))
    assert plan.status.fallback == "none"
    assert 100.0 - 1e-6 <= plan.u[0, 0] <= 250.0 + 1e-6


@pytest.mark.slow
def test_mpc_respects_the_temperature_ceiling(model):
    # target from a hot schedule (400 rpm continuous, peak ~ 120 C); rpm >= 400 and a 60 C ceiling:
    # not reachable, the MPC mills as long as the ceiling allows
    Xs = model.simulate(model.x0(), [[400.0, 1.0]] * 4, DT)
    ceiling = 60.0
    ctrl = make_controller(mpc_cfg(temperature={"ceiling_c": ceiling}, bounds={"rpm_min": 400.0}), model,
                           {"s_mean_um": float(Xs[-1, 0]), "r_mean": float(Xs[-1, 2])})
    x, plans, U, X = closed_loop(model, ctrl, 2.0)
    peaks = [float(peak_temperature(model, X[k, 4], X[k, 5], U[k, 0], U[k, 1], DT)) for k in range(len(U))]
    assert max(peaks) <= ceiling + 0.05
    assert max(X[:, 4]) <= ceiling + 0.05
    assert all(p.status.fallback == "none" for p in plans)
    assert max(p.status.slack_max_c for p in plans) < 0.05
    assert not any(p.status.violation for p in plans)
    # the ceiling is active, not avoided by resting: the plans sit on it; the applied inputs lose
    # at most one minute of milling to the (temperature-safe) minute rounding
    assert max(p.t_peak_c[0] for p in plans) > ceiling - 0.1
    assert max(peaks) > ceiling - 10.0


@pytest.mark.slow
def test_peak_temperature_matches_the_model_step(model):
    x = model.x0().copy()
    x[4] = 40.0
    for rpm, m in ((300.0, 0.5), (450.0, 0.8), (200.0, 1.0)):
        want = model.step(x, [rpm, 1.0], m * DT)[4]
        assert float(peak_temperature(model, x[4], x[5], rpm, m, DT)) == pytest.approx(want, rel=1e-9)


# --- fallback ----------------------------------------------------------------------------------


@pytest.mark.slow
def test_fallback_rest_when_max_iter_is_zero(model):
    ctrl = make_controller(mpc_cfg(horizon=2, solver={"max_iter": 0}), model, {"s_mean_um": 50.0})
    plan = ctrl.plan(model.x0(), 0.0)
    st = plan.status
    assert not st.success and st.fallback == "rest"
    assert st.solver_status == "Maximum_Iterations_Exceeded"
    assert "Maximum_Iterations_Exceeded" in st.reason
    assert np.array_equal(plan.u_apply, [0.0, 0.0])
    assert "fallback rest" in st.line()


@pytest.mark.slow
def test_fallback_shifted_plan_on_injected_infeasibility(model):
    # a truly hard ceiling (slack_max_c = 0) below ambient is infeasible: even a rest starts at 25 C
    ctrl = make_controller(mpc_cfg(horizon=3, batch_hours=3.0, temperature={"ceiling_c": 80.0, "slack_max_c": 0.0},
                                   solver={"max_iter": 40}),
                           model, {"s_mean_um": 50.0})
    first = ctrl.plan(model.x0(), 0.0)
    assert first.status.fallback == "none"
    x1 = model.step(model.x0(), first.u_apply, DT)
    ctrl.cfg.temperature.ceiling_c = 20.0  # inject the infeasible hard constraint
    plan = ctrl.plan(x1, DT, None, first.u_apply)
    st = plan.status
    assert not st.success and st.fallback == "shifted", st.line()
    assert st.solver_status not in ("Solve_Succeeded", "Solved_To_Acceptable_Level")
    assert st.solver_status in st.reason and "shifted" in st.reason
    assert plan.u[0, 0] == pytest.approx(np.clip(first.u[1, 0], 100, 500), abs=1e-6)
    assert plan.u_apply[1] == 0.0  # the guard of the shifted plan: no milling above the ceiling
    assert st.violation  # the ceiling cannot be met: reported
    # no previous plan: rest
    ctrl.reset()
    st2 = ctrl.plan(x1, DT).status
    assert st2.fallback == "rest" and not st2.success


# --- on/off ------------------------------------------------------------------------------------


def test_applied_input_rounds_milling_to_whole_minutes():
    assert np.allclose(applied_input((300.0, 0.337), 0.5), [300.0, 10 / 30])
    assert np.allclose(applied_input((300.0, 0.99), 0.5), [300.0, 1.0])
    assert np.allclose(applied_input((300.0, 0.01), 0.5), [0.0, 0.0])  # 0.3 min -> rest
    assert np.allclose(applied_input((250.0, 0.337), 0.5, round_minutes=False), [250.0, 0.337])
    assert np.allclose(applied_input((250.0, 0.6), 0.5, binary=True), [250.0, 1.0])
    assert np.allclose(applied_input((250.0, 0.4), 0.5, binary=True), [0.0, 0.0])
    for m in np.linspace(0, 1, 37):
        u = applied_input((300.0, m), 2 / 3)
        assert abs(u[1] * 40 - round(u[1] * 40)) < 1e-9


@pytest.mark.slow
def test_rounding_never_pushes_over_the_ceiling(model):
    x = model.x0().copy()
    # a milling share whose peak is just at the ceiling: rounding up would exceed it
    for m in np.linspace(0.05, 0.95, 19):
        ceiling = float(peak_temperature(model, x[4], x[5], 450.0, m, DT))
        a = applied_input_guarded(model, x, (450.0, m), DT, ceiling)
        assert float(peak_temperature(model, x[4], x[5], a[0], a[1], DT)) <= ceiling + 1e-9
        assert abs(a[1] * 30 - round(a[1] * 30)) < 1e-9


@pytest.mark.slow
def test_binary_mode_gives_on_off_inputs_and_reports_the_loss(model):
    ctrl = make_controller(mpc_cfg(horizon=3, batch_hours=1.5, onoff={"mode": "binary"},
                                   temperature={"ceiling_c": 70.0}),
                           model, {"s_mean_um": 60.0, "r_mean": 0.12})
    plan = ctrl.plan(model.x0(), 0.0)
    assert plan.status.fallback == "none", plan.status.line()
    assert set(np.unique(plan.u[:, 1])) <= {0.0, 1.0}
    assert plan.u_apply[1] in (0.0, 1.0)
    assert plan.status.binary_loss is not None and np.isfinite(plan.status.binary_loss)


def test_schedule_segments_mill_then_rest():
    segs = schedule_segments(np.array([[300.0, 0.5], [300.0, 1.0], [0.0, 0.0], [350.0, 1.0]]), 0.5)
    assert segs == [(0.25, 300.0), (0.25, 0.0), (0.5, 300.0), (0.5, 0.0), (0.5, 350.0)]


# --- references ---------------------------------------------------------------------------------


@pytest.mark.slow
def test_time_varying_reference_per_interval(model):
    ref = Reference([(0.0, {"s_mean_um": 60.0}), (1.0, {"s_mean_um": 45.0, "r_mean": 0.05})])
    assert ref.at(0.5) == {"s_mean_um": 60.0} and ref.at(1.0)["s_mean_um"] == 45.0
    ctrl = make_controller(mpc_cfg(horizon=4, batch_hours=2.0), model, ref)
    data = ctrl._problem_data(model.x0(), 0.0, model.p0(), None)
    ny, n = 7, 4  # per interval: (s_mean, s_std, r_mean, r_std, d50, d90, span) lo, then hi, then weights
    lo = data["P"][8:8 + ny * n].reshape(n, ny)
    hi = data["P"][8 + ny * n:8 + 2 * ny * n].reshape(n, ny)
    assert lo[0, 0] == 60.0 and lo[1, 0] == 45.0 and lo[3, 0] == 45.0 and np.array_equal(lo, hi)  # points
    q = data["P"][8 + 2 * ny * n:8 + 3 * ny * n].reshape(n, ny)
    assert q[0, 2] == 0.0 and q[1, 2] > 0.0  # r_mean enters once the reference names it

    assert q[3, 0] > 10 * q[2, 0]  # terminal weight at the batch end
    cfg = validate_controller({"kind": "mpc", "target": {"s_mean_um": 40.0},
                               "reference": [{"from_h": 2.0, "s_mean_um": 30.0}]}, "t")
    assert Reference.from_config(cfg).at(3.0) == {"s_mean_um": 30.0}


@pytest.mark.slow
def test_batch_end_inside_the_horizon(model):
    ctrl = make_controller(mpc_cfg(horizon=4, batch_hours=1.25), model, {"s_mean_um": 50.0})
    data = ctrl._problem_data(model.x0(), 0.0, model.p0(), None)
    assert np.allclose(data["m_ub"], [1.0, 1.0, 0.5, 0.0])
    assert data["k_end"] == 3
    plan = ctrl.plan(model.x0(), 1.25)
    assert plan.status.solver_status == "batch_done" and plan.u_apply[1] == 0.0


# --- baselines ---------------------------------------------------------------------------------


@pytest.mark.slow
def test_recipe_controllers(model):
    c = make_controller(CTRL / "recipe-400rpm-30-10.toml", model)
    assert c.interval_h == pytest.approx(40 / 60)
    plan = c.plan(model.x0(), 0.0)
    assert np.allclose(plan.u_apply, [400.0, 0.75])
    assert c.milling_fraction(0.25, 0.75) == pytest.approx((0.25 + 1 / 12) / c.interval_h)
    c = make_controller(CTRL / "recipe-300rpm-continuous.toml", model)
    x, plans, U, X = closed_loop(model, c, 2.0)
    assert np.allclose(U, [[300.0, 1.0]] * 4)
    assert np.allclose(x, model.simulate(model.x0(), [[300.0, 1.0]] * 4, DT)[-1], rtol=1e-6)


@pytest.mark.slow
def test_lqr_baseline_bounds_rate_and_temperature_guard(model):
    cfg = load_controller(CTRL / "lqr-baseline.toml")
    cfg = cfg.model_copy(update={"batch_hours": 3.0,  # rpm >= 400: the 60 C guard must act
                                 "bounds": cfg.bounds.model_copy(update={"rpm_min": 400.0}),
                                 "temperature": cfg.temperature.model_copy(update={"ceiling_c": 60.0})})
    Xs = model.simulate(model.x0(), [[450.0, 1.0]] * 6, DT)
    ctrl = make_controller(cfg, model, {"s_mean_um": float(Xs[-1, 0])})
    x, plans, U, X = closed_loop(model, ctrl, 3.0)
    check_rpm_limits(U, cfg.bounds.rpm_min, cfg.bounds.rpm_max, cfg.bounds.rpm_step_max)
    peaks = [float(peak_temperature(model, X[k, 4], X[k, 5], U[k, 0], U[k, 1], DT)) for k in range(len(U))]
    assert max(peaks) <= 60.0 + 1e-6
    assert any("temperature guard" in p.status.reason for p in plans)
    assert all(p.status.controller == "lqr" and p.status.success for p in plans)


# --- configs and the CLI -----------------------------------------------------------------------


@pytest.mark.slow
def test_shipped_controller_files_load(model):
    for f in sorted(CTRL.glob("*.toml")):
        make_controller(f, model)
    assert load_controller(CTRL / "mpc-fast.toml").horizon < load_controller(CTRL / "mpc-default.toml").horizon


def test_parse_target():
    assert parse_target("s_mean_um=25, r_mean=0.05") == {"s_mean_um": 25.0, "r_mean": 0.05}
    for bad in ("foo=1", "s_mean_um=nan", "s_mean_um", "s_mean_um=-3", "r_mean=1.5", "", "s_mean_um=1,s_mean_um=2"):
        with pytest.raises(InputError):
            parse_target(bad)


def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


@pytest.mark.parametrize("case", ["missing", "malformed", "unknown-field", "bad-value", "no-kind", "recipe",
                                  "bad-target", "nan-target", "d90-below-d50", "neg-hours", "nan-hours",
                                  "bad-model"])
def test_design_bad_input_one_line_exit_2(tmp_path, capsys, case):
    ctrl = str(CTRL / "mpc-fast.toml")
    target, hours, card = "s_mean_um=45", "1", str(CARD)
    if case == "missing":
        ctrl = str(tmp_path / "nope.toml")
    elif case == "malformed":
        ctrl = str(_write(tmp_path, "c.toml", 'kind = "mpc"\nhorizon = [\n'))
    elif case == "unknown-field":
        ctrl = str(_write(tmp_path, "c.toml", 'kind = "mpc"\n[weights]\nterminl = 3\n'))
    elif case == "bad-value":
        ctrl = str(_write(tmp_path, "c.toml", 'kind = "mpc"\n[bounds]\nrpm_min = 400\nrpm_max = 300\n'))
    elif case == "no-kind":
        ctrl = str(_write(tmp_path, "c.toml", "horizon = 4\n"))
    elif case == "recipe":
        ctrl = str(CTRL / "recipe-400rpm-30-10.toml")
    elif case == "bad-target":
        target = "s_mean=45"
    elif case == "nan-target":
        target = "s_mean_um=nan"
    elif case == "d90-below-d50":  # no size law has it: refused before any search
        target = "d50_um=45,d90_um=40"
    elif case == "neg-hours":
        hours = "-2"
    elif case == "nan-hours":
        hours = "nan"
    elif case == "bad-model":
        card = str(tmp_path / "none.toml")
    out = tmp_path / "out"
    rc = main(["design", card, "--target", target, "--hours", hours, "--controller", ctrl, "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("bmctl: error: "), err
    assert "Traceback" not in err
    assert not out.exists()


@pytest.mark.slow
def test_design_writes_a_schedule_simulate_reads(tmp_path, capsys, model):
    out = tmp_path / "d"
    Xs = model.simulate(model.x0(), [[300.0, 1.0]] * 2, DT)
    rc = main(["design", str(CARD), "--target", f"s_mean_um={Xs[-1, 0]:.3f}", "--hours", "1",
               "--controller", str(CTRL / "mpc-fast.toml"), "--out", str(out)])
    txt = capsys.readouterr().out
    assert rc == 0, txt
    sched = load_schedule(out / "schedule.toml")
    total = sum(s.hours for s in sched.segment)
    assert total <= 1.0 + 1e-6
    assert all(s.rpm <= 500 for s in sched.segment)
    assert all(abs(s.hours * 60 - round(s.hours * 60)) < 1e-6 for s in sched.segment)
    rows = (out / "predicted.csv").read_text(encoding="utf-8").splitlines()
    assert rows[0].startswith("t_h,rpm,milling,t_peak_c,s_mean_um") and len(rows) >= 1 + 2  # one row per segment end
    assert (out / "design.png").stat().st_size > 1000
    s_final = float(rows[-1].split(",")[4])
    assert s_final == pytest.approx(Xs[-1, 0], rel=0.03)
    assert math.isfinite(s_final)
    header = (out / "schedule.toml").read_text(encoding="utf-8").splitlines()[1]  # the prediction of the target's own quantity
    predicted = float(header.split("predicted s_mean_um ")[1].split()[0])
    assert predicted == pytest.approx(s_final, rel=1e-3) and "D50" not in header


def test_window_target_has_lo_below_hi_and_no_cost_inside(model):
    ctrl = make_controller(mpc_cfg(horizon=2, batch_hours=1.0), model, {"d50_um": (40.0, 50.0)})
    data = ctrl._problem_data(model.x0(), 0.0, model.p0(), None)
    ny, n = 7, 2
    lo = data["P"][8:8 + ny * n].reshape(n, ny)
    hi = data["P"][8 + ny * n:8 + 2 * ny * n].reshape(n, ny)
    assert lo[-1, 4] == 40.0 and hi[-1, 4] == 50.0


def test_design_starts_on_threads_give_the_sequential_design(model):
    """The relaxed starts run side by side on threads, each with its own solver: same starts, same design."""
    from bmctl.control.pattern import STARTS, PatternDesigner

    cfg = load_controller(CTRL / "mpc-default.toml")
    target = {"s_mean_um": 45.0}
    starts = {}
    for threads in (1, STARTS):
        cfg = cfg.model_copy(update={"solver": cfg.solver.model_copy(update={"design_threads": threads})})
        d = PatternDesigner(model, 3.0, cfg, target)
        starts[threads] = d._relaxed_starts(*d._bounds())[0]
    assert len(starts[1]) == STARTS
    for (f1, x1), (f3, x3) in zip(starts[1], starts[STARTS]):
        assert f1 == f3
        np.testing.assert_array_equal(x1, x3)
    assert len({f for f, _ in starts[1]}) > 1  # the starts are distinct solves
