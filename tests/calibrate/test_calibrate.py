"""bmctl calibrate and the Dask layer: seeding across workers, history errors, cards, recovery."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bmctl.calibrate.fit import FitSettings
from bmctl.calibrate.history import load_history
from bmctl.calibrate.outputs import calibrated_card, write_card
from bmctl.calibrate.params import get_param, parse_params, set_params
from bmctl.calibrate.writeback import card_from_multipliers
from bmctl.cli import main
from bmctl.config import load_card, with_factors
from bmctl.errors import InputError
from bmctl.parallel import client_for, close_client, ensemble_map, seed_sequences

from tests.conftest import card_path

LAB = card_path("alni-1to1-300rpm-lab")


def _plant_task(task, rng):
    """A short plant run and one draw: what a calibration or whatif task does."""
    from bmctl.plant.plant import Plant

    plant = Plant(load_card(LAB), rng, task["particles"])
    plant.advance(task["rpm"], task["hours"])
    return float(plant.s.mean()), float(plant.r.mean()), float(rng.random())


TASKS = [{"particles": 200, "rpm": rpm, "hours": 0.2} for rpm in (200.0, 300.0, 300.0, 400.0, 0.0)]


@pytest.fixture(scope="module")
def clusters():
    from distributed import Client, LocalCluster

    made = []
    for n in (1, 2):
        cluster = LocalCluster(n_workers=n, processes=False, threads_per_worker=1, dashboard_address=":0",
                               silence_logs=40)
        made.append(Client(cluster))
    yield made
    for c in made:
        close_client(c)


@pytest.mark.slow
def test_one_and_two_workers_give_identical_results(clusters):
    serial = ensemble_map(_plant_task, TASKS, 11)
    one, two = (ensemble_map(_plant_task, TASKS, 11, c) for c in clusters)
    assert one == serial and two == serial
    # tasks 1 and 2 differ only in their stream: spawned generators are independent
    assert serial[1] != serial[2]
    assert ensemble_map(_plant_task, TASKS, 12) != serial


def test_seed_sequences_are_numpy_spawn():
    a = seed_sequences(5, 3)
    b = np.random.SeedSequence(5).spawn(3)
    assert [x.generate_state(2).tolist() for x in a] == [x.generate_state(2).tolist() for x in b]


def test_client_for_serial_below_two_workers():
    assert client_for(None, 0) is None and client_for(None, 1) is None
    with pytest.raises(InputError, match="^workers: "):  # from Python; the commands name --workers
        client_for(None, -1)


# --- history files ------------------------------------------------------------------------

def _table(path: Path, n: int = 20, seed: int = 0):
    rng = np.random.default_rng(seed)
    s = rng.lognormal(np.log(40), 0.3, n)
    r = rng.uniform(0, 0.4, n)
    path.write_text("s_um,r\n" + "\n".join(f"{a:.4f},{b:.4f}" for a, b in zip(s, r)) + "\n", encoding="utf-8")


def _history(tmp_path: Path, text: str) -> Path:
    _table(tmp_path / "t1.csv")
    _table(tmp_path / "t2.csv", seed=1)
    p = tmp_path / "hist.toml"
    p.write_text(text, encoding="utf-8")
    return p


#: a history's schedule and its two samples (tables t1.csv, t2.csv), apart and together
SEGMENTS = """
[[segment]]
hours = 3
rpm = 300
"""
SAMPLES = """
[[sample]]
t_h = 1.0
table = "t1.csv"
[[sample]]
t_h = 2.0
table = "t2.csv"
"""
GOOD = SEGMENTS + SAMPLES


@pytest.mark.slow
def test_history_loads(tmp_path):
    h = load_history(_history(tmp_path, GOOD), load_card(LAB))
    assert h.times_h == [1.0, 2.0] and h.segments == [(3.0, 300.0, 1.0)]
    assert h.samples[0].s_um.size == 20


@pytest.mark.parametrize("text, field", [
    (GOOD.replace('t_h = 2.0', 't_h = 0.5'), "sample[1].t_h"),
    (GOOD.replace('t_h = 2.0', 't_h = 4.0'), "sample[1].t_h"),
    (GOOD.replace('table = "t2.csv"', 'table = "t2.csv"\nimage = "x.png"'), "sample[1]"),
    (GOOD.replace('table = "t2.csv"', 'image = "t2.png"'), "sample[1].image"),
    (GOOD.replace('rpm = 300', 'rpm = 900'), "segment[0].rpm"),
    (GOOD.replace('rpm = 300', 'rpm = 300\nspeed = 2'), "segment[0].speed"),
    (GOOD.replace('t_h = 1.0', 't_h = -1.0'), "sample[0].t_h"),
    (GOOD.replace('table = "t1.csv"', 'table = "missing.csv"'), "missing.csv"),
    ('schedule = "s.toml"\n' + GOOD, "schedule"),
    (GOOD.replace('hours = 3', 'hours = 3\nmilling = 1.5'), "segment[0].milling"),
])
def test_history_errors_are_one_line_naming_file_and_field(tmp_path, text, field):
    p = _history(tmp_path, text)
    with pytest.raises(InputError) as err:
        load_history(p, load_card(LAB))
    msg = str(err.value)
    assert "\n" not in msg
    assert field in msg
    assert str(tmp_path) in msg


def test_history_image_needs_scale(tmp_path):
    from PIL import Image

    Image.fromarray(np.zeros((32, 32), dtype=np.uint8)).save(tmp_path / "t2.png")
    p = _history(tmp_path, GOOD.replace('table = "t2.csv"', 'image = "t2.png"'))
    with pytest.raises(InputError, match=r"hist.toml: sample\[1\].um_per_px: required"):
        load_history(p)


# --- parameters and cards -----------------------------------------------------------------

def test_named_parameters():
    card = load_card(LAB)
    assert parse_params("gamma, delta,partition.strain_efficiency", card) == \
        ["gamma", "delta", "partition.strain_efficiency"]
    new = set_params(card, {"alpha": 3.0, "thermal.softening_max": 0.3})
    assert new.stochastic.alpha == 3.0 and new.thermal.softening_max == 0.3
    assert get_param(new, "beta") == card.stochastic.beta
    for bad in ("epsilon", "stochastic.nothing", "card.name", ""):
        with pytest.raises(InputError, match="^names: "):  # from Python; bmctl calibrate names --params
            parse_params(bad, card)
    with pytest.raises(InputError, match="stochastic.gamma_per_um2"):
        set_params(card, {"gamma": -1.0})


def test_calibrated_card_loads(tmp_path):
    card = load_card(LAB)
    new = calibrated_card(card, ["gamma", "delta"], [2.5e-4, 6e-4], "test note")
    p = write_card(tmp_path / "x-calibrated.toml", new)
    back = load_card(p)
    assert back.model_dump() == new.model_dump()
    assert back.stochastic.gamma_per_um2 == 2.5e-4 and back.card.name.endswith("-calibrated")
    assert back.partition == card.partition and back.thermal == card.thermal


def test_estimate_writeback_multiplies_gamma_delta():
    card = load_card(LAB)
    new = card_from_multipliers(card, 1.4, 0.75, "filter")
    ref = with_factors(card, 1.4, 0.75)
    assert new.stochastic.gamma_per_um2 == pytest.approx(ref.stochastic.gamma_per_um2, rel=1e-12)
    assert new.stochastic.delta_per_um2 == pytest.approx(ref.stochastic.delta_per_um2, rel=1e-12)


def test_cli_bad_history_one_line(tmp_path, capsys):
    p = _history(tmp_path, GOOD.replace('t_h = 2.0', 't_h = 0.5'))
    rc = main(["calibrate", str(LAB), str(p), "--out", str(tmp_path / "out"), "--workers", "0"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "\n" not in err and "sample[1].t_h" in err
    assert main(["calibrate", str(LAB), str(p), "--params", "gamma,zeta", "--workers", "0"]) == 2


@pytest.mark.slow
def test_cli_calibrate_small_end_to_end(tmp_path, capsys, monkeypatch):
    from functools import partial

    from bmctl.calibrate.synthetic import synthetic_history, write_history
    from bmctl.moments import forcard

    # the calibrated card's moment identification at `bmctl identify --quick --jacobians 2` size (~20 s, not
    # ~2 min): what is checked here is calibrate's outputs; the identification's own tests are in tests/moments/
    monkeypatch.setattr(forcard, "identification_text",
                        partial(forcard.identification_text, quick=True, jacobians=2))

    truth = with_factors(load_card(LAB), 1.4, 0.75)
    h = synthetic_history(truth, [(1.0, 300.0, 1.0)], [0.5, 1.0], 150, 400, np.random.default_rng(3), name="tiny")
    hp = write_history(h, tmp_path)
    out = tmp_path / "out"
    out.mkdir()  # an earlier calibration's outputs: its figure of another history goes, the user's file stays
    (out / "calibration.json").write_text(json.dumps({"histories": [{"name": "old run"}, {"name": "tiny"}]}), encoding="utf-8")
    for f in ("histograms-old_run.png", "histograms-tiny.png", "histograms-mine.png"):
        (out / f).write_bytes(b"")
    rc = main(["calibrate", str(LAB), str(hp), "--params", "gamma,delta", "--particles", "200", "--workers", "0",
               "--out", str(out), "--seed", "2"])
    assert rc == 0
    assert not (out / "histograms-old_run.png").exists() and (out / "histograms-mine.png").exists()
    assert f"removed {out / 'histograms-old_run.png'}" in capsys.readouterr().out
    card = load_card(out / "alni-1to1-300rpm-lab-calibrated.toml")
    data = json.loads((out / "calibration.json").read_text(encoding="utf-8"))
    est = data["parameters"]["gamma"]
    assert est["interval90"][0] <= est["estimate"] <= est["interval90"][1]
    assert card.stochastic.gamma_per_um2 == pytest.approx(est["estimate"])
    assert (out / "histograms-tiny.png").stat().st_size > 0
    # the coefficients written beside the calibrated card are its own
    assert forcard.for_card(out / "alni-1to1-300rpm-lab-calibrated.toml").coeff_file.card_name == card.card.name


@pytest.mark.slow
def test_seeded_recovery_of_gamma_delta():
    """A synthetic truth of the bias study's family (benchmarks/calibrate_bias.py, seed 1004: lab card,
    gamma x 0.97, delta x 0.68, 300 particles at 2, 4, 6, 8 h of a 300 rpm run): both estimates within
    +-15 % and the truth inside both 90 % intervals. The study's cases mostly land within +-11 %
    (docs/calibration-from-data.md), so 15 % is a tolerance the method meets, not a hope."""
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
    from calibrate_bias import case

    client = client_for(None, 2)
    try:
        row = case(1004, client, FitSettings())
    finally:
        close_client(client)
    for name in ("gamma", "delta"):
        r = row[name]
        assert r["lo90"] <= r["truth"] <= r["hi90"], (name, r)
        assert abs(r["rel_err"]) <= 0.15, (name, r)


def test_fisher_information_is_debiased_for_simulation_noise():
    """Summaries linear in u with known J plus independent replicate noise: the mean of the
    debiased J'WJ over many draws is the true J'WJ (a parameter with no effect gets ~0)."""
    from bmctl.calibrate.fit import _design, _jacobian_information

    rng = np.random.default_rng(4)
    n, R, h = 12, 2, 0.3
    J_true = np.zeros((n, 2))
    J_true[:, 0] = rng.normal(0, 1, n)  # parameter 1 has no effect
    W = np.eye(n)
    pts = _design(np.zeros(2), h)
    Fs = []
    for _ in range(2000):
        S = (pts @ J_true.T)[:, None, :] + rng.normal(0, 0.5, (pts.shape[0], R, n))
        Fs.append(_jacobian_information(S, W, h)[1])
    F_mean = np.mean(Fs, axis=0)
    truth = J_true.T @ W @ J_true
    assert F_mean[0, 0] == pytest.approx(truth[0, 0], rel=0.1)
    # undebiased, the no-effect parameter would get n * 2 * 0.5^2 / (R * 4 h^2) = 8.3 on average; debiased,
    # the clipping of negative eigenvalues (a 1-dof noise estimate at R = 2) leaves a positive mean: at least
    # half of the noise term must go
    undebiased = n * 2 * 0.5**2 / (R * 4 * h**2)
    assert F_mean[1, 1] < 0.5 * undebiased


@pytest.mark.slow
def test_estimate_write_card(tmp_path):
    from bmctl.calibrate.synthetic import synthetic_history, write_history

    truth = with_factors(load_card(LAB), 1.4, 0.75)
    h = synthetic_history(truth, [(2.0, 300.0, 1.0)], [1.0, 2.0], 150, 600, np.random.default_rng(0), name="wb")
    write_history(h, tmp_path)
    out = tmp_path / "next.toml"
    rc = main(["estimate", str(LAB), "--samples", str(tmp_path / "wb-t0.csv"), str(tmp_path / "wb-t1.csv"),
               "--times", "1,2", "--particles", "200", "--out", str(tmp_path / "est.csv"), "--write-card", str(out)])
    assert rc == 0
    card, nxt = load_card(LAB), load_card(out)
    row = (tmp_path / "est.csv").read_text(encoding="utf-8").splitlines()
    header, last = row[0].split(","), row[-1].split(",")
    g = float(last[header.index("gamma_mult")])
    d = float(last[header.index("delta_mult")])
    assert nxt.stochastic.gamma_per_um2 == pytest.approx(card.stochastic.gamma_per_um2 * g, rel=1e-4)
    assert nxt.stochastic.delta_per_um2 == pytest.approx(card.stochastic.delta_per_um2 * d, rel=1e-4)


def test_ridge_posterior_reproduces_a_gaussian_posterior():
    """Summaries linear in u (no plant noise): the posterior is Gaussian with precision J'WJ + P and
    mean H^-1 J'W y. The ridge scan, started away from the mean, must give its median and its 5 %
    and 95 % quantiles (up to the grid's cell spread: variance x (1 + 1/12) along the ridge)."""
    from scipy.stats import norm

    from bmctl.calibrate.fit import FitSettings, ridge_posterior

    J = np.array([[1.0, 0.9], [0.8, 0.75], [0.5, 0.48], [0.2, 0.1]]) * 6.0  # a strongly correlated pair
    W = np.eye(4)
    P = np.eye(2)
    y = J @ np.array([0.4, -0.3]) + np.array([0.3, -0.2, 0.1, 0.05])

    class Linear:
        def run(self, pts):
            return np.stack([np.stack([J @ u] * 2) for u in pts])

    H = J.T @ W @ J + P
    cov = np.linalg.inv(H)
    mean = cov @ J.T @ W @ y
    u0 = mean + 1.5 * np.sqrt(np.diag(cov)) * np.array([1.0, -1.0])  # where Gauss-Newton might have stopped
    u_hat, lo, hi, cov_r, info = ridge_posterior(Linear(), y, W, P, J, H, u0, FitSettings())
    sd = np.sqrt(np.diag(cov))
    np.testing.assert_allclose(u_hat, mean, atol=0.02 * sd.max())
    z = norm.ppf(0.95)
    np.testing.assert_allclose(hi - u_hat, z * sd, rtol=0.06)
    np.testing.assert_allclose(u_hat - lo, z * sd, rtol=0.06)
    assert len(info["points"]) >= 7  # extended until both ends are in the tails


def test_ridge_posterior_of_a_parameter_the_data_ignore_is_the_prior():
    """A parameter the summaries do not respond to: its posterior is the prior N(0, 1) in ln units,
    so the scan (capped at 3 prior sd) must return the prior's median and 5 %/95 % quantiles."""
    from scipy.stats import norm

    from bmctl.calibrate.fit import FitSettings, ridge_posterior

    J = np.array([[4.0, 0.0], [2.0, 0.0], [1.0, 0.0]])
    W, P = np.eye(3), np.eye(2)
    y = J @ np.array([0.2, 0.0])

    class Linear:
        def run(self, pts):
            return np.stack([np.stack([J @ u] * 2) for u in pts])

    H = J.T @ W @ J + P
    u_hat, lo, hi, _, _ = ridge_posterior(Linear(), y, W, P, J, H, np.array([0.2, 0.5]), FitSettings())
    assert abs(u_hat[1]) < 0.05
    np.testing.assert_allclose([lo[1], hi[1]], norm.ppf([0.05, 0.95]), rtol=0.06)


def test_local_information_reports_identifiability_without_a_fit():
    """``local_information`` (used by ``benchmarks/calibrate_accuracy.py four``): one design at a point,
    a positive semi-definite Fisher information, posterior sd no wider than the prior's, one verdict
    with its reason per parameter; the same seed gives the same numbers."""
    from bmctl.calibrate.fit import FitSettings, local_information
    from bmctl.calibrate.synthetic import synthetic_history

    truth = with_factors(load_card(LAB), 1.4, 0.75)
    h = synthetic_history(truth, [(1.0, 300.0, 1.0)], [0.5, 1.0], 150, 400, np.random.default_rng(3), name="tiny")
    s = FitSettings(particles=200)
    a = local_information(load_card(LAB), [h], ["gamma", "delta"], np.log([1.4, 0.75]), seed=1, settings=s)
    assert a["plant_runs"] == (2 * 2 + 1) * s.replicates
    assert a["fisher"].shape == (2, 2) and np.all(np.linalg.eigvalsh(a["fisher"]) >= -1e-9)
    assert np.all(a["sd_ratio"] <= 1.0 + 1e-12) and len(a["identified"]) == len(a["why"]) == 2
    b = local_information(load_card(LAB), [h], ["gamma", "delta"], np.log([1.4, 0.75]), seed=1, settings=s)
    np.testing.assert_array_equal(a["fisher"], b["fisher"])


@pytest.mark.parametrize("log, chi2, expect", [
    ([{"step_in_sd": 3.0}, {"step_in_sd": 1.5}], 14.0, "more iterations"),
    ([{"step_in_sd": 1.0}, {"step_in_sd": 1.4, "action": "step"}, {"action": "worse: step halved"}], 14.0, "noisy"),
    ([{"step_in_sd": 1.0}, {"step_in_sd": 1.2}], 400.0,
     "does not reach the data (chi2 400 on 16 summaries at the last Gauss-Newton step)"),
    ([{"step_in_sd": 1.0}, {"step_in_sd": 1.2}], 14.0, "another time or rpm"),
])
def test_unconverged_fit_says_why_and_what_would_help(log, chi2, expect):
    from bmctl.calibrate.fit import _stop_reason

    s = FitSettings(max_iter=len(log))
    text = _stop_reason(log, False, s, chi2, 16)
    assert text.startswith(f"not converged: iteration cap {len(log)} reached") and expect in text
    assert "\n" not in text
    assert _stop_reason([{"step_in_sd": 0.3}], True, s, 10.0, 16).startswith("converged")


def test_a_trial_value_beyond_a_constants_range_is_run_at_its_bound():
    """The fit moves u = ln(value / card value) freely; a bounded constant (softening_max < 1, alpha <= 20)
    must be run at its bound, not refused mid-fit by the card's validation."""
    from bmctl.calibrate.fit import _Evaluator
    from types import SimpleNamespace

    from bmctl.calibrate.simulate import simulate_task

    card = load_card(LAB)
    names = ["thermal.softening_max", "alpha", "gamma"]
    ev = _Evaluator(card, names, [], FitSettings(), [], None, None)
    u = np.array([2.0, 3.0, -1.0])  # 0.45 e^2 = 3.3 > 1; 2.1 e^3 = 42 > 20; gamma well inside
    vals = ev.values(u)
    assert vals[0] < 1.0 and vals[0] == pytest.approx(1.0) and vals[1] == 20.0
    assert vals[2] == pytest.approx(card.stochastic.gamma_per_um2 * np.exp(-1.0))
    hist = SimpleNamespace(segments=[(0.2, 300.0, 1.0)], times_h=[0.2])  # what a task reads of a history
    summ, _ = simulate_task(ev.task(u, hist), np.random.default_rng(0))
    assert np.all(np.isfinite(summ))


def test_an_estimate_at_a_constants_bound_is_not_called_identified():
    """softening_max pushed past 1 and alpha past 20 are run at their bounds; their posterior sd can be
    narrow (the plant no longer responds past the bound), which printed them as identified."""
    from bmctl.calibrate.fit import _Evaluator, _identifiability, bounds_hit

    card = load_card(LAB)
    names = ["thermal.softening_max", "alpha", "gamma"]
    ev = _Evaluator(card, names, [], FitSettings(), [], None, None)
    u = np.array([2.0, -4.0, -1.0])  # 0.45 e^2 = 3.3 > 1; 2.1 e^-4 = 0.04 < 0.1; gamma well inside
    assert bounds_hit(ev, u) == ["upper", "lower", None]
    s = FitSettings()
    ok, why = _identifiability(names, np.eye(3) * 400.0, np.full(3, 0.05), s, bounds_hit(ev, u))
    assert ok == [False, False, True]
    assert "upper bound" in why[0] and "lower bound" in why[1] and "posterior sd" in why[2]


def test_ridge_posterior_never_scores_a_point_below_zero():
    """The profile -2 ln posterior (chi2 + u'Pu after a conditional Gauss-Newton step) is a sum of
    squares. Where J does not describe a grid point -- far from where it was taken, or with H's
    information debiased below J'WJ -- the predicted step took it below zero, and that one point took
    all the weight: on data the card could not reach (sizes in mm read as um) the estimate jumped to
    ln gamma = -24 with a zero-width interval. A step predicted below zero is not taken."""
    from bmctl.calibrate.fit import FitSettings, ridge_posterior

    J = np.array([[1.0, 0.9], [0.8, 0.75], [0.5, 0.48], [0.2, 0.1]]) * 6.0
    W, P = np.eye(4), np.eye(2)
    y = J @ np.array([3.0, -2.0]) + np.array([4.0, -3.0, 2.0, 1.0])  # far from every point the model reaches

    class Linear:
        def run(self, pts):
            return np.stack([np.stack([J @ u] * 2) for u in pts])

    H = 0.05 * J.T @ W @ J + P  # the noise-debiased information: well below J'WJ
    u0 = np.array([0.5, 0.2])
    u_hat, lo, hi, _, info = ridge_posterior(Linear(), y, W, P, J, H, u0, FitSettings())
    q = [pt["minus2_log_posterior"] for pt in info["points"]]
    assert min(q) >= 0.0, q
    assert np.all(np.abs(u_hat) <= 3.0 * FitSettings().prior_sd + np.abs(u0)), u_hat


def test_cli_warns_of_a_sample_outside_the_cards_size_range(tmp_path, capsys):
    """A table in mm read as µm (sizes ~0.05 µm, inside the 1 nm..10 mm a table may hold) was fitted
    without a word; like `bmctl simulate` for a run, calibrate now names the sample whose mean size
    lies outside the card's range of validity (before any work: refused here by the budget)."""
    _table(tmp_path / "t1.csv")
    (tmp_path / "mm.csv").write_text("s_um,r\n" + "".join(f"{0.04 + 0.001 * k:g},0.2\n" for k in range(30)), encoding="utf-8")
    p = tmp_path / "hist.toml"
    p.write_text(GOOD.replace('"t2.csv"', '"mm.csv"'), encoding="utf-8")
    rc = main(["calibrate", str(LAB), str(p), "--params", "gamma,delta", "--out", str(tmp_path / "out"),
               "--workers", "0", "--budget-cpu-h", "1e-9"])
    err = capsys.readouterr().err
    assert rc == 2
    warns = [ln for ln in err.splitlines() if ln.startswith("bmctl: warning:")]
    assert len(warns) == 1 and "sample[1]" in warns[0] and "outside the card's" in warns[0], err


def test_the_moment_start_of_samples_that_saw_no_milling_is_the_card():
    """A history sampled only at 0 h says nothing of gamma and delta: the moment model's likelihood is
    the same over its whole grid, and the first maximum, the grid's corner (x1/4, x1/4), was reported
    as the first stage's optimum. Among equal points the start is the card's value."""
    from bmctl.calibrate.moment_start import moment_start
    from bmctl.calibrate.synthetic import synthetic_history

    h = synthetic_history(load_card(LAB), [(1.0, 300.0, 1.0)], [0.0], 150, 400, np.random.default_rng(3), name="feed")
    u0, info = moment_start(LAB, [h], ["gamma", "delta"])
    np.testing.assert_array_equal(u0, [0.0, 0.0])
    assert (info["gamma_mult"], info["delta_mult"]) == (1.0, 1.0)
