"""The moment model: one definition for numpy and casadi, realisability, plant agreement, CLI errors."""

import math

import numpy as np
import pytest

from bmctl.cli import main
from bmctl.errors import InputError
from bmctl.moments import equations as eq
from bmctl.moments import make_moment_model
from bmctl.moments.coeffs import coeffs_path

from ..conftest import CARDS, card_path

LAB = card_path("alni-1to1-300rpm-lab")


@pytest.fixture(scope="module")
def model():
    return make_moment_model(LAB)


def _states(model, n=6, seed=3):
    """Realisable states spread over the operating range (from short model runs)."""
    rng = np.random.default_rng(seed)
    xs = []
    for _ in range(n):
        x = model.x0()
        for _ in range(int(rng.integers(0, 4))):
            x = model.step(x, [rng.uniform(50, 600), rng.uniform(0.3, 1.0)], 1.0)
        xs.append(x)
    return np.array(xs)


# --- one definition, numpy and casadi -------------------------------------------------------------


@pytest.mark.slow
def test_numpy_and_casadi_agree(model):
    import casadi as ca

    F = model.casadi_step(0.5)
    f = model.casadi_rhs()
    rng = np.random.default_rng(0)
    for x in _states(model):
        u = np.array([rng.uniform(0, 600), rng.uniform(0, 1)])
        p = np.array([rng.uniform(0.5, 2), rng.uniform(0.5, 2)])
        xn = model.step(x, u, 0.5, p)
        xc = np.array(F(x, u, p)).ravel()
        np.testing.assert_allclose(xn, xc, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(model.rhs(x, u, p), np.array(f(x, u, p)).ravel(), rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(model.rhs(x, u, p), np.array(model.rhs(ca.DM(x), ca.DM(u), ca.DM(p), xp=ca)).ravel(),
                                   rtol=1e-9, atol=1e-12)
        # the public rate field (what every RKC stage evaluates) against the numpy definition
        y = eq.to_y(eq.NP, list(x[:4]))
        a = [x[4], x[5], u[0] / model.rpm_max, p[0], p[1]]
        np.testing.assert_allclose(np.array(model.rate_function()(y, a)).ravel(),
                                   eq.y_rates(eq.NP, model.const, model.coeffs, y, *a), rtol=1e-9, atol=1e-12)


def test_batched_step_equals_single_steps(model):
    X = _states(model, 4)
    U = np.array([[100.0, 1.0], [300.0, 0.5], [600.0, 1.0], [0.0, 1.0]])
    P = np.array([[1.0, 1.0], [1.5, 0.7], [0.8, 1.2], [1.0, 1.0]])
    batch = model.step(X, U, 0.5, P)
    for k in range(4):
        np.testing.assert_allclose(batch[k], model.step(X[k], U[k], 0.5, P[k]), rtol=1e-12)
    sim = model.simulate(X[0], np.tile(U[1], (3, 1)), 0.5, P[1])
    x = X[0]
    for _ in range(3):
        x = model.step(x, U[1], 0.5, P[1])
    np.testing.assert_allclose(sim[-1], x, rtol=1e-9)


@pytest.mark.slow
def test_casadi_jacobian_matches_finite_differences(model):
    import casadi as ca

    F = model.casadi_step(0.5)
    xs, us, ps = ca.SX.sym("x", 6), ca.SX.sym("u", 2), ca.SX.sym("p", 2)
    J = ca.Function("J", [xs, us, ps], [ca.jacobian(F(xs, us, ps), ca.vertcat(xs, us, ps))])
    x = _states(model, 3)[-1]
    u, p = np.array([350.0, 0.8]), np.array([1.1, 0.9])
    Ja = np.array(J(x, u, p))
    z0 = np.concatenate([x, u, p])
    Jn = np.zeros_like(Ja)
    for k in range(10):
        h = 1e-6 * max(abs(z0[k]), 1e-2)
        zp, zm = z0.copy(), z0.copy()
        zp[k] += h
        zm[k] -= h
        fp = model.step(zp[:6], zp[6:8], 0.5, zp[8:])
        fm = model.step(zm[:6], zm[6:8], 0.5, zm[8:])
        Jn[:, k] = (fp - fm) / (2 * h)
    scale = np.abs(Ja).max(axis=1, keepdims=True) + 1e-12
    np.testing.assert_allclose(Ja / scale, Jn / scale, atol=1e-5)


# --- realisability -----------------------------------------------------------------------------


@pytest.mark.parametrize("bad", [
    [40.0, -3.0, 0.1, 0.05, 25.0, 0.0],      # negative std
    [40.0, 0.0, 0.1, 0.05, 25.0, 0.0],       # zero std
    [-5.0, 4.0, 0.1, 0.05, 25.0, 0.0],       # negative mean size
    [40.0, 4.0, 1.3, 0.05, 25.0, 0.0],       # r_mean > 1
    [40.0, 4.0, -0.2, 0.05, 25.0, 0.0],      # r_mean < 0
    [40.0, 4.0, 0.1, 0.6, 25.0, 0.0],        # r_std^2 > r_mean (1 - r_mean): no Beta law
    [40.0, 4.0, 0.0, 0.0, 25.0, 0.0],        # degenerate r
])
def test_unrealisable_states_are_projected(model, bad):
    x = np.array(bad)
    for u in ([300.0, 1.0], [600.0, 1.0], [0.0, 1.0]):
        xn = model.step(x, u, 0.5)
        assert np.all(np.isfinite(xn))
        assert xn[0] > 0 and xn[1] > 0
        assert 0 < xn[2] < 1 and 0 < xn[3] ** 2 < xn[2] * (1 - xn[2])
    assert np.all(np.isfinite(model.rhs(x, [300.0, 1.0])))
    s, r = model.distributions(x)
    assert np.isfinite(s.mean()) and s.std() > 0
    assert 0 < r.mean() < 1 and r.std() > 0
    assert np.isfinite(model.loglik(x, [10.0, 40.0, 90.0], [0.0, 0.1, 0.5]))


@pytest.mark.parametrize("beta", [-1.0, 0.5, 4.0])
def test_steps_stay_realisable_across_the_s_r_link_bounds(model, beta):
    """Identification may try any r_size_corr within its bounds [-1, 4]: every step from random
    states and inputs stays finite and realisable (r of a size node is capped below 1)."""
    from bmctl.moments.model import MomentModel

    m = MomentModel(model.card, dict(model.coeffs, r_size_corr=beta))
    rng = np.random.default_rng(0)
    n = 300
    X = np.column_stack([rng.uniform(5, 150, n), rng.uniform(0.5, 80, n), rng.uniform(0, 0.9, n),
                         rng.uniform(0, 0.5, n), rng.uniform(20, 100, n), rng.uniform(0, 1, n)])
    U = np.column_stack([rng.uniform(0, 600, n), rng.uniform(0, 1, n)])
    Y = m.step(X, U, 0.5)
    assert np.all(np.isfinite(Y)) and np.all(np.isfinite(m.rhs(X, U)))
    assert np.all(Y[:, 0] > 0) and np.all(Y[:, 1] > 0)
    assert np.all((Y[:, 2] > 0) & (Y[:, 2] < 1)) and np.all(Y[:, 3] ** 2 < Y[:, 2] * (1 - Y[:, 2]))


def test_distributions_reproduce_the_moments(model):
    for x in _states(model):
        s, r = model.distributions(x)
        assert s.mean() == pytest.approx(x[0], rel=1e-6)
        assert s.std() == pytest.approx(x[1], rel=1e-6)
        assert r.mean() == pytest.approx(x[2], rel=1e-5)
        assert r.std() == pytest.approx(x[3], rel=1e-5)


def test_loglik_is_vectorised_and_prefers_the_true_state(model):
    x_true = _states(model, 3)[-1]
    s, r = model.distributions(x_true)
    rng = np.random.default_rng(5)
    s_um, rr = s.rvs(300, random_state=rng), r.rvs(300, random_state=rng)
    other = x_true.copy()
    other[0] *= 1.3
    ll = model.loglik(np.stack([x_true, other]), s_um, rr)
    assert ll.shape == (2,) and ll[0] > ll[1]
    assert model.loglik(x_true, s_um, rr, sum_over=False).shape == (300,)
    with pytest.raises(InputError):
        model.loglik(x_true, [1.0, np.nan], [0.1, 0.1])


# --- agreement with the plant ------------------------------------------------------------------


#: worst held-out NRMSE per moment allowed for the lab card's model (pinned; identification
#: measured 0.081, 0.073, 0.202, 0.145 on the shipped coefficients)
WORST_NRMSE = {"s_mean_um": 0.085, "s_std_um": 0.075, "r_mean": 0.21, "r_std": 0.15}


def test_short_case_follows_plant_ensemble(model):
    """2 h at the card's 300 rpm from the card's powder, against 4 seeded plants (M = 2000).

    Tolerance per moment and time = 3 standard errors of the ensemble mean (the plant's own
    spread) plus the model error allowed for this card: 3 x a worst held-out NRMSE pinned here
    (:data:`WORST_NRMSE`, the values identification reported for the shipped coefficients,
    rounded up; a pointwise error is up to ~3x an RMSE) times the trajectory's range. Nothing
    here is read from the artefact under test; the first-hours growth transient is the
    model's weakest region (docs/moments.md, Sec. 6).
    """
    from bmctl.plant import make_plant

    names = ("s_mean_um", "s_std_um", "r_mean", "r_std", "temperature_c")
    worst = WORST_NRMSE
    runs = []
    for seed in range(4):
        plant = make_plant(LAB, seed=seed, particles=2000)
        traj = []
        for _ in range(4):
            plant.advance(300.0, 0.5)
            m = plant.moments()
            traj.append([m[k] for k in names])
        runs.append(traj)
    Y = np.array(runs)  # seeds x times x moments
    mean, se = Y.mean(0), Y.std(0, ddof=1) / math.sqrt(Y.shape[0])
    pred = model.simulate(model.x0(), np.tile([300.0, 1.0], (4, 1)), 0.5)[1:, :5]
    span = np.ptp(np.vstack([model.x0()[:5], mean]), axis=0)
    allowance = 3 * np.array([worst[k] for k in names[:4]] + [0.0]) * span
    tol = 3 * se + allowance + 1e-9
    assert np.all(np.abs(pred - mean) <= tol), (pred, mean, tol)
    # temperature follows the same closed form as the plant: exact
    np.testing.assert_allclose(pred[:, 4], mean[:, 4], rtol=1e-9)


def test_bond_shape_averaged_over_the_plants_contact_length():
    """The r of a new bond (eqn 18) over the plant's random contact length (eqn 16 under the
    energy law of eqn 5): the model's 4-bin quadrature against a Monte Carlo of the plant's own
    functions, at a mean energy where 1/3 of the bonds come out exactly round (r clipped at 0)
    and 1/6 of the contacts reach the cap of eqn 16.

    Tolerances: 2 % of E[r] and 5 % of E[r^2] (the quadrature's bins and the smooth clip at 0;
    the Monte Carlo's own error is < 0.5 %). The mean contact alone (the previous closure)
    misses both by a factor > 2, so the check can tell the two apart.
    """
    from bmctl.moments import equations as eq
    from bmctl.moments.physics import impact_factors
    from bmctl.plant import events as ev

    nodes = impact_factors(2.1, 1.8)["contact_nodes"]
    assert len(nodes) == 4 and math.isclose(sum(w for w, _ in nodes), 1.0)
    u, _ = ev.sample_impact_energies(np.random.default_rng(7), 1.0, 200_000)  # not the nodes' stream
    si, sj, ri, rj, modulus, u_mean = 40e-6, 30e-6, 0.05, 0.10, 120e9, 0.01
    d = ev.hertz_contact_length(si, sj, u_mean * u / u.mean(), modulus)
    _, r = ev.bonded(si, ri, sj, rj, d)
    assert 0.2 < np.mean(r == 0) < 0.5 and 0.05 < np.mean(d >= 0.999 * np.pi / 2 * sj) < 0.3
    d_pi = 2 * ev.hertz_contact_length(si, sj, u_mean, modulus) / math.pi
    args = (math.hypot(si, sj), si / (1 - ri) + sj / (1 - rj), d_pi)
    m1, m2 = eq.bond_r_moments(eq.NP, *args, nodes)
    assert abs(m1 - r.mean()) <= 0.02 * r.mean(), (m1, r.mean())
    assert abs(m2 - np.mean(r * r)) <= 0.05 * np.mean(r * r), (m2, np.mean(r * r))
    o1, o2 = eq.bond_r_moments(eq.NP, *args, ((1.0, 1.0),))
    assert o1 < 0.5 * r.mean() and o2 < 0.5 * np.mean(r * r)


@pytest.mark.parametrize("name", CARDS)
def test_size_shape_link_has_the_plants_sign(name):
    """The closure's s-r link (``r_size_corr``, the slope of logit E[r | s] in ln s) points the
    way the plant's does: after 2 h at 300 rpm the plant's mean r rises with size (slope of
    logit E[r | s quintile] on ln s > 0.5; measured 1.8-2.9, docs/moments.md Sec. 6), and
    identification gave every card beta > 0."""
    import tomllib

    from bmctl.plant import make_plant

    path = coeffs_path(card_path(name))
    if not path.exists():
        pytest.skip(f"no identified coefficients for {name}")
    beta = tomllib.loads(path.read_text(encoding="utf-8"))["coefficients"].get("r_size_corr", 0.0)
    plant = make_plant(card_path(name), seed=1, particles=3000)
    plant.advance(300.0, 2.0)
    ls, r = np.log(plant.s), plant.r
    edges = np.quantile(ls, np.linspace(0, 1, 6))
    idx = np.clip(np.searchsorted(edges, ls, side="right") - 1, 0, 4)
    mr = np.clip([r[idx == k].mean() for k in range(5)], 1e-4, None)
    slope = np.polyfit([ls[idx == k].mean() for k in range(5)], np.log(mr / (1 - mr)), 1)[0]
    assert slope > 0.5, slope
    assert beta > 0, beta


@pytest.mark.slow
def test_identification_recovers_known_coefficients(model):
    """``identify.fit`` (casadi with the coefficients as symbols, exact Jacobian, bounded least
    squares) recovers coefficients that generated the data, from the built-in defaults: the
    bonding scale, the s-r link beta and the rounding scale, on three short schedules."""
    from bmctl.moments import identify as ident
    from bmctl.moments.model import MomentModel

    true = {"bond_log_scale": 0.3, "r_size_corr": 0.5, "round_log_scale": 0.4}
    mt = MomentModel(model.card, dict(model.coeffs, **true))
    exps = []
    for name, U in (("a", [[300.0, 1.0]] * 8), ("b", [[500.0, 1.0]] * 4 + [[150.0, 1.0]] * 4),
                    ("c", [[400.0, 0.5]] * 8)):
        Y = mt.simulate(mt.x0(), np.array(U), 0.5)
        exps.append(ident.Experiment(name, np.array(U), Y, np.zeros_like(Y)))
    res = ident.fit(model, exps, free=tuple(true))
    assert res.cost < 1e-6 * res.cost0
    for k, v in true.items():
        assert res.coeffs[k] == pytest.approx(v, abs=1e-4), k


def test_residual_scales_sit_between_own_and_common_range():
    """The fit divides each run's residual by the geometric mean of that run's own range and the
    range over all runs: a run in which a moment hardly moves gets more weight than under the
    common range, but less than under its own (docs/moments.md, Sec. 6)."""
    from bmctl.moments import identify as ident

    t = np.linspace(0.0, 1.0, 9)[:, None]
    flat = 10.0 + 0.5 * t * np.ones((1, 6))  # range 0.5, floored at 10 % of the mean (~1.0)
    steep = 10.0 + 20.0 * t * np.ones((1, 6))  # range 20
    exps = [ident.Experiment(n, np.zeros((8, 2)), Y, np.zeros_like(Y)) for n, Y in (("flat", flat), ("steep", steep))]
    sc = ident.run_scales(exps)
    common = ident.scales(exps)
    assert sc.shape == (2, 6)
    assert np.allclose(common, 20.0)
    assert np.allclose(sc[0], np.sqrt(ident.span(flat) * 20.0))
    assert np.all(ident.span(flat) < sc[0]) and np.all(sc[0] < common)
    assert np.allclose(sc[1], 20.0)


@pytest.mark.slow
def test_response_to_gamma_delta_follows_the_plant(model):
    """p = the plant's (gamma, delta) factors act inside eqns (15) and (20), nothing fitted: the
    model told p must follow plants with gamma, delta 30 % off the card. Compared: ln of the
    s_mean ratio (off-card / card) at 1-4 h of the lab recipe, plant ensemble (2 seeds x 3000)
    against the model. Tolerance 0.08 (measured on the shipped coefficients: 0.041 and 0.037;
    0.07 and 0.13 on an earlier set, when the tolerance was 0.15; the seed noise of a ratio is
    ~0.03). The structure it replaced (p multiplying the averaged rates c_b, c_f) is 0.31 and
    0.06 off: worse on both plants, and outside the tolerance on the first."""
    from bmctl.config import with_factors
    from bmctl.moments.model import MomentModel
    from bmctl.plant.plant import Plant

    def plant_s(card):
        out = []
        for seed in (1, 2):
            plant = Plant(card, np.random.default_rng(seed), 3000)
            row = []
            for _ in range(4):
                plant.advance(300.0, 1.0)
                row.append(plant.moments()["s_mean_um"])
            out.append(row)
        return np.mean(out, axis=0)

    U = [[300.0, 1.0]] * 4
    base_plant = plant_s(model.card)
    base_model = model.simulate(model.x0(), U, 1.0)[1:, 0]
    tol, direct_errs = 0.08, []
    for p in [(1.3, 0.7), (0.7, 1.3)]:
        plant_ratio = np.log(plant_s(with_factors(model.card, *p)) / base_plant)
        model_ratio = np.log(model.simulate(model.x0(), U, 1.0, p=np.array(p))[1:, 0] / base_model)
        assert np.sign(plant_ratio[-1]) == np.sign(model_ratio[-1])
        err = np.max(np.abs(model_ratio - plant_ratio))
        assert err < tol, (p, plant_ratio, model_ratio)
        # the test can fail: p as direct multipliers on the averaged rates misses by more
        direct = MomentModel(model.card, {**model.coeffs,
                                          "bond_log_scale": model.coeffs["bond_log_scale"] + np.log(p[0]),
                                          "frac_log_scale": model.coeffs["frac_log_scale"] + np.log(p[1])}, "direct")
        direct_ratio = np.log(direct.simulate(direct.x0(), U, 1.0)[1:, 0] / base_model)
        direct_errs.append(np.max(np.abs(direct_ratio - plant_ratio)))
        assert direct_errs[-1] > err, (p, plant_ratio, direct_ratio)
    assert max(direct_errs) > tol + 0.05, direct_errs


# --- linear analysis ---------------------------------------------------------------------------


@pytest.mark.slow
def test_linearize_gives_statespace(model):
    import control

    x = _states(model, 2)[-1]
    sys_c = model.linearize(x, [300.0, 1.0])
    sys_d = model.linearize(x, [300.0, 1.0], dt_h=0.5)
    assert isinstance(sys_c, control.StateSpace) and sys_c.dt == 0
    assert sys_d.dt == 0.5 and sys_d.A.shape == (6, 6) and sys_d.B.shape == (6, 2) and sys_d.C.shape == (4, 6)
    # temperature responds to rpm and milling as dT/dt = P/C - (T - T_amb)/tau
    assert sys_c.A[4, 4] == pytest.approx(-1 / model.const.cooling_time_h)


@pytest.mark.slow
def test_linearize_command(tmp_path, capsys):
    assert main(["linearize", str(LAB), "--at-hours", "2", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "controllability rank" in out and "observability rank" in out
    assert list(tmp_path.glob("*.png"))


# --- coefficients and bad inputs -----------------------------------------------------------------


def test_bad_coefficient_file_is_an_input_error(tmp_path):
    bad = tmp_path / "x.moments.toml"
    bad.write_text("[coefficients]\nbond_log_scale = nan\n", encoding="utf-8")
    with pytest.raises(InputError, match="bond_log_scale"):
        make_moment_model(LAB, coeffs=bad)
    bad.write_text("[coefficients]\nnot_a_coefficient = 1.0\n", encoding="utf-8")
    with pytest.raises(InputError, match="unknown"):
        make_moment_model(LAB, coeffs=bad)


@pytest.mark.slow
@pytest.mark.parametrize("name", CARDS)
def test_every_card_builds_and_runs(name):
    m = make_moment_model(card_path(name))
    X = m.simulate(m.x0(), [[m.card.process.rpm, 1.0]] * 4, 1.0)
    assert np.all(np.isfinite(X)) and X.shape == (5, 6)


def _card_with(tmp_path, old, new):
    text = LAB.read_text(encoding="utf-8").replace(old, new)
    p = tmp_path / "card.toml"
    p.write_text(text, encoding="utf-8")
    return p


@pytest.mark.parametrize("argv_tail, what", [
    (["--particles", "-5"], "--particles"),
    (["--particles", "nan"], "--particles"),
    (["--seed", "abc"], "--seed"),
    (["--random-schedules", "-1"], "--random-schedules"),
    (["--random-schedules", "4.5"], "--random-schedules"),
    (["--bogus"], "unrecognized"),
])
def test_identify_bad_flags(tmp_path, capsys, argv_tail, what):
    out = tmp_path / "c.moments.toml"
    rc = main(["identify", str(LAB), "--out", str(out), *argv_tail])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and err[0].startswith("bmctl: error:") and what in err[0]
    assert not out.exists()


def test_identify_missing_card(tmp_path, capsys):
    card = tmp_path / "nope.toml"
    assert main(["identify", str(card)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("bmctl: error:") and "not found" in err[0]
    assert not coeffs_path(card).exists()


def test_identify_nan_in_card(tmp_path, capsys):
    card = _card_with(tmp_path, "yield_stress_Pa = 78.7e6", "yield_stress_Pa = nan")
    assert main(["identify", str(card)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("bmctl: error:") and "yield_stress_Pa" in err[0]
    assert not coeffs_path(card).exists()


def test_identify_report_names_each_miss_and_its_margin():
    """The report's verdict names every moment above the 5 % target with its margin, and says met only
    when none is (NaN counts as a miss)."""
    from bmctl.commands.identify import _target_line

    names = ["s_mean_um", "s_std_um", "r_mean", "r_std", "temperature_c"]
    line = _target_line(names, [0.032, 0.025, 0.055, 0.052, 0.0])
    assert "NOT met" in line and "r_mean 5.5 % (+0.5 points)" in line and "r_std 5.2 % (+0.2 points)" in line
    assert "s_mean_um" not in line and "temperature_c" not in line
    assert _target_line(names, [0.05, 0.01, 0.02, 0.03, 0.0]).endswith(": met")
    assert "s_std_um nan" in _target_line(names, [0.01, float("nan"), 0.02, 0.03, 0.0])
    assert "r_std 5.04 % (+0.04 points)" in _target_line(names, [0.01, 0.01, 0.02, 0.0504, 0.0])


def test_identify_out_is_a_folder(tmp_path, capsys):
    assert main(["identify", str(LAB), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--out" in err[0]


def test_coefficient_file_text_is_valid_toml_with_any_key():
    import tomllib

    from bmctl.moments.coeffs import toml_text

    text = toml_text({"bond_log_scale": 0.1}, {"validation": {"n": 2, "sensitivity": {"recipe-g1.3-d0.7, s_mean_um": 0.1,
                                                                                      'odd "key"': 2.0}}})
    data = tomllib.loads(text)
    assert data["coefficients"]["bond_log_scale"] == 0.1
    assert data["validation"]["sensitivity"] == {"recipe-g1.3-d0.7, s_mean_um": 0.1, 'odd "key"': 2.0}


def test_coarser_casadi_step_is_stable_and_close(model):
    # fewer RKC substeps (more stages) for the MPC: stable at the top speed, close to the default
    # (2 substeps are not: r_std drifts by 45 % over 6 h at 600 rpm)
    x = model.x0()
    F, F2 = model.casadi_step(0.5), model.casadi_step(0.5, 3)  # 3: the MPC default
    a, b = x.copy(), x.copy()
    for _ in range(12):
        a = np.asarray(F(a, [model.rpm_max, 1.0], [1.0, 1.0])).ravel()
        b = np.asarray(F2(b, [model.rpm_max, 1.0], [1.0, 1.0])).ravel()
    assert np.all(np.isfinite(b))
    np.testing.assert_allclose(b, a, rtol=5e-3, atol=1e-4)
    with pytest.raises(InputError):
        model.casadi_step(0.5, 0)


def test_fast_forms_equal_the_textbook_forms():
    """The rate field's speed rewrites (docs/moments.md, Sec. 8) compute the same numbers as the
    plain formulas they replace: eqn 16's capped contact length via -8th powers against
    smin_pos(d_h, (pi/2) smin_pos(si, sj)), and the logit link's shared-exponential sigmoids
    against sigmoid(a + beta sigma t_k). Relative tolerance 1e-12 (float rounding only), over
    sizes 0.1-500 um, mean energies over 8 decades and link slopes across their bounds."""

    def smin_pos(a, b, n=8):  # the textbook smooth minimum of eqn 16's cap, (a^-n + b^-n)^(-1/n)
        return np.exp(-np.log(np.exp(-n * np.log(a)) + np.exp(-n * np.log(b))) / n)

    def sigmoid(v):
        return 1.0 / (1.0 + np.exp(-v))

    rng = np.random.default_rng(5)
    B = eq.NP
    si, sj = 10 ** rng.uniform(-1, 2.7, (2, 4000))
    uu = 10 ** rng.uniform(-6, 2, 4000)
    d_h = 0.75 * si * sj / (si + sj) * np.sqrt(uu / (si**3 + sj**3))
    d_ref = smin_pos(d_h, 0.5 * np.pi * smin_pos(si, sj))
    cap = (0.5 * np.pi) ** -8 * (si**-8.0 + sj**-8.0)
    d_fast = 1.0 / eq._inv_contact(B, 0.75 * si, si, sj, si**3 + sj**3, cap, uu)
    np.testing.assert_allclose(d_fast, d_ref, rtol=1e-12)

    a = rng.uniform(-9, 9, 4000)
    k = rng.uniform(-1, 6, 4000) * rng.uniform(0.01, 2.0, 4000)  # beta * sigma_ln
    fast = eq.node_sigmoids(B, a, eq.node_exps(B, -k))
    for t, sg in zip(eq.GH_T, fast):
        np.testing.assert_allclose(sg, sigmoid(a + k * t), rtol=1e-12)


@pytest.mark.slow
def test_identify_figures_show_best_median_and_worst(tmp_path):
    """The validation figure picks its schedules by the mean NRMSE of the particle moments (and writes PNGs)."""
    from bmctl import plots
    from bmctl.moments import identify as ident

    model = make_moment_model(LAB)
    U = np.array([[300.0, 1.0]] * 4 + [[0.0, 0.0]] * 2 + [[450.0, 0.5]] * 2)
    X = model.simulate(model.x0(), U, 0.5)
    exps, preds = [], []
    for k in [3, 0, 4, 1, 2]:  # plant = model x (1 + 0.02 k): the error grows with k, listed out of order
        exps.append(ident.Experiment(f"run-{k}", U, X * (1 + 0.02 * k), 0.01 * np.abs(X)))
        preds.append(X)
    rows = np.array([ident.nrmse(P, e.Y) for P, e in zip(preds, exps)])
    shown = plots.identify_validation(tmp_path / "v.png", exps, preds, rows, "test")
    assert shown == ["run-0", "run-2", "run-3", "run-4"]  # best, median, 2nd worst, worst
    plots.identify_nrmse(tmp_path / "n.png", rows, 2 * rows, "test")
    for name in ("v.png", "n.png"):
        assert (tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_identify_unwritable_figures_folder(tmp_path, capsys):
    blocker = tmp_path / "afile"
    blocker.write_text("x", encoding="utf-8")
    assert main(["identify", str(LAB), "--out", str(tmp_path / "c.toml"), "--figures", str(blocker / "f")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("bmctl: error: --figures:") and len(err.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


def test_frac_link_shift_acts_on_the_fracture_terms_only():
    """The fracture terms' own link slope (docs/moments.md, Sec. 2): with fracture switched off the
    field does not depend on it; with fracture on it moves the shape rates."""
    model = make_moment_model(LAB)
    c, q0 = model.const, dict(model.coeffs)
    state = (45.0, 25.0, 0.12, 0.11, 45.0, 0.3)  # s_mean, s_std, r_mean, r_std, T, h
    m, sd, rm, rs, T, h = state
    rho = rs / math.sqrt(rm * (1 - rm))

    def rates(**over):
        return np.array(eq.raw_rates(eq.NP, c, {**q0, **over}, m, sd, rm, rho, T, h, 0.5, 1.0, 1.0))

    off_a = rates(frac_log_scale=-40.0, frac_link_shift=-2.0)
    off_b = rates(frac_log_scale=-40.0, frac_link_shift=2.0)
    assert np.allclose(off_a, off_b, rtol=1e-12, atol=0)
    on_a, on_b = rates(frac_link_shift=-2.0), rates(frac_link_shift=2.0)
    assert abs(on_a[2] - on_b[2]) > 1e-3 * abs(on_a[2])  # dE[r]/dt moves


def test_design_more_random_schedules_extends_the_same_stream():
    """``design(n_random=N)`` keeps the structured runs and the first random schedules of a
    smaller design and adds new ones (the refits of docs/moments.md compare designs this way)."""
    from bmctl.config import load_card
    from bmctl.moments import identify as ident

    card = load_card(LAB)
    on_card = lambda specs: [s for s in specs if s.factors == (1.0, 1.0)]  # noqa: E731
    base = ident.design(card, 0)
    more = ident.design(card, 0, n_random=ident.N_RANDOM_TRAIN + 4)
    assert len(more) == len(base) + 4
    for a, b in zip(on_card(base), on_card(more)):
        assert a.name == b.name and a.inputs == b.inputs and a.prefix == b.prefix
    extra = on_card(more)[len(on_card(base)):]
    assert len(extra) == 4 and all(s.name.startswith("random-train-") for s in extra)
    assert all(s.inputs != b.inputs for s in extra for b in base)
    assert len(ident.design(card, 0, quick=True, n_random=0)) == len(ident.design(card, 0, quick=True)) - 2
    # the off-card training plants do not depend on n_random
    off = lambda specs: [(s.name, s.factors, s.inputs) for s in specs if s.factors != (1.0, 1.0)]  # noqa: E731
    assert off(base) == off(more) and len(off(base)) == len(ident.TRAIN_FACTORS) * (1 + ident.N_RANDOM_OFF_CARD)
    assert {s[1] for s in off(base)} == set(ident.TRAIN_FACTORS)


def test_event_counts_balance_the_particle_number(model):
    """Bonds remove and fractures add a particle while sum s^2 is conserved (eqns 2, 18, 20), so over
    every interval ln(E[s^2] before / after) = fractures - bonds per particle: the event counts and
    the moments come from the same rates, integrated together."""
    U = np.array([[300.0, 1.0], [0.0, 1.0], [550.0, 0.5], [120.0, 0.8]])
    X = model.simulate(model.x0(), U, 1.0)
    C = model.event_counts(model.x0(), U, 1.0)
    es2 = X[:, 0] ** 2 + X[:, 1] ** 2
    np.testing.assert_allclose(np.log(es2[:-1] / es2[1:]), C[:, 1] - C[:, 0], atol=1e-6)
    assert np.all(C[[0, 2, 3]] > 0.01) and np.all(C[1] < 1e-4)  # rest: none (the rates are smoothed at rpm 0)


@pytest.mark.slow
@pytest.mark.parametrize("name", CARDS)
def test_event_rates_follow_the_plants_counts_on_the_recipe(name):
    """The fit sees moments only, never the plant's event counts: here the bonds and fractures
    per particle that the model predicts on the card's recipe (12 h at the process rpm, then a
    0.5-h rest) are compared with a plant's (seed 0, M = 4000), per 0.5-h interval from 2 h on.
    Bound: |ln(model / plant)| <= 0.3 (35 %) per interval, what docs/moments.md (Sec. 6) states
    for the recipe; measured 2-12 h: -0.12 ... +0.18 on the three cards, seeds 0 and 1 (shipped
    coefficients; -0.02 ... +0.23 on an earlier set). The rest
    interval records no plant events, and < 1e-4 per particle in the model (its rates are smooth
    at rpm 0)."""
    from bmctl.config import load_card
    from bmctl.moments import identify as ident

    card = load_card(card_path(name))
    rpm = card.process.rpm
    spec = ident.Spec("recipe", [(rpm, 1.0)] * 24 + [(0.0, 1.0)])
    e = ident.run_experiments(card, [spec], [0], 4000)[0]
    assert e.events.shape == (25, 2) and np.all(e.events[-1] == 0.0)
    C = make_moment_model(card_path(name)).event_counts(e.x0, e.U, e.dt_h, e.p)
    assert np.all(C[-1] < 1e-4)  # the model's rates are smooth at rpm 0, so 'none' is < 1e-4
    lr = np.log(C[4:24] / e.events[4:24])
    assert np.all(np.abs(lr) <= 0.3), lr


def test_event_counts_agree_in_numpy_and_casadi(model):
    """The counters ride in the same step in both evaluators (the casadi rate field with events)."""
    import casadi as ca

    x, u = model.x0(), [420.0, 0.7]
    n, st = model._integration(0.5)
    _, rates = eq.casadi_rate_field(model.const, model.coeffs, events=True)
    out = eq.step(eq.CA(), model.const, model.coeffs, [ca.DM(v) for v in x], u, [1.0, 1.0], 0.5, n, st,
                  rates=rates, events=True)
    got = np.array([float(ca.evalf(v)) for v in out])
    want_x = model.step(x, u, 0.5)
    want_c = model.event_counts(x, [u], 0.5)[0]
    np.testing.assert_allclose(got[:6], want_x, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(got[6:], want_c, rtol=1e-9)


def test_cv_link_coefficients_steepen_the_link_where_r_is_spread():
    """``r_link_cv_slope`` and ``frac_link_cv_shift`` (docs/moments.md, Sec. 2): at 0 the
    field is the one without them, bit for bit; the fracture one acts on the fracture terms only;
    and the link they set depends on the state's CV of r (two states with the same r_mean)."""
    model = make_moment_model(LAB)
    c = model.const
    q0 = {k: v for k, v in model.coeffs.items() if k not in ("r_link_cv_slope", "frac_link_cv_shift")}
    m, sd, T, h = 45.0, 25.0, 45.0, 0.3

    def rates(rm, rs, **over):
        rho = rs / math.sqrt(rm * (1 - rm))
        return np.array(eq.raw_rates(eq.NP, c, {**q0, **over}, m, sd, rm, rho, T, h, 0.5, 1.0, 1.0))

    base = rates(0.12, 0.11)
    assert np.array_equal(base, rates(0.12, 0.11, r_link_cv_slope=0.0, frac_link_cv_shift=0.0))
    off_a = rates(0.12, 0.11, frac_log_scale=-40.0, frac_link_cv_shift=-1.0)
    off_b = rates(0.12, 0.11, frac_log_scale=-40.0, frac_link_cv_shift=1.0)
    assert np.allclose(off_a, off_b, rtol=1e-12, atol=0)
    for k in ("r_link_cv_slope", "frac_link_cv_shift"):
        assert abs(rates(0.12, 0.11, **{k: 1.0})[2] - base[2]) > 1e-3 * abs(base[2])
    # k ln CV^2 with CV = 1 adds nothing to the slope; at another CV it does
    assert np.allclose(rates(0.1, 0.1, r_link_cv_slope=1.0), rates(0.1, 0.1), rtol=1e-9, atol=0)
    assert not np.allclose(rates(0.1, 0.2, r_link_cv_slope=1.0), rates(0.1, 0.2), rtol=1e-6, atol=0)
