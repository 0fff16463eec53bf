"""UKF estimator (tracking, coverage, state round trip, settings) and Generator-driven resampling."""

from __future__ import annotations

import csv
import pickle

import numpy as np
import pytest
from pydantic import ValidationError

from bmctl.cli import main
from bmctl.config import validate
from bmctl.errors import InputError
from bmctl.estimate.filter import FilterSettings, ParticleFilter
from bmctl.estimate.likelihood import LawSettings, beta_params, weibull_params
from bmctl.estimate.resampling import SCHEMES, multinomial, residual, resample, stratified, systematic
from bmctl.estimate.run import make_estimator
from bmctl.estimate.ukf import UKFEstimator, UKFSettings, make_pd

from tests.conftest import ROOT, card_path

LAB = str(card_path("alni-1to1-300rpm-lab"))
P_TRUE = np.array([1.3, 0.7])  # the mismatch scenario's gamma, delta factors
U300 = np.array([300.0, 1.0])


@pytest.fixture(scope="module")
def model():
    from bmctl.moments.model import make_moment_model

    return make_moment_model(LAB)


def draw_sample(x: np.ndarray, n: int, rng: np.random.Generator, law: LawSettings = LawSettings()):
    """n measured particles from the stated laws of state x: Weibull s with multiplicative
    noise sigma_log_s, Beta r through additive noise sigma_r and the floor r_meas = max(0, r + e)."""
    k, lnlam = weibull_params(x[0], x[1])
    s_um = np.exp(lnlam) * rng.weibull(k, n) * np.exp(law.sigma_log_s * rng.standard_normal(n))
    a, b = beta_params(x[2], x[3])
    r = np.clip(rng.beta(a, b, n) + law.sigma_r * rng.standard_normal(n), 0.0, 0.999)
    return s_um, r


# --- resampling ------------------------------------------------------------------------------
def _weights(rng, N):
    w = rng.gamma(0.5, size=N)
    return w / w.sum()


@pytest.mark.parametrize("scheme", SCHEMES)
def test_resampling_reproducible_and_global_state_untouched(scheme):
    w = _weights(np.random.default_rng(0), 50)
    np.random.seed(123)
    before = np.random.get_state()
    a = resample(w, np.random.default_rng(9), scheme)
    b = resample(w, np.random.default_rng(9), scheme)
    after = np.random.get_state()
    assert np.array_equal(a, b) and a.size == 50 and a.min() >= 0 and a.max() < 50
    assert before[0] == after[0] and np.array_equal(before[1], after[1]) and before[2:] == after[2:]


def test_systematic_counts_within_floor_ceil():
    rng = np.random.default_rng(1)
    for _ in range(200):
        N = int(rng.integers(2, 60))
        w = _weights(rng, N)
        c = np.bincount(systematic(w, rng), minlength=N)
        assert np.all(c >= np.floor(N * w - 1e-9)) and np.all(c <= np.ceil(N * w + 1e-9))


def test_stratified_counts_within_one_stratum_of_expected():
    # one point per stratum: an interval of length N w meets at most ceil(N w) + 1 strata
    rng = np.random.default_rng(2)
    for _ in range(200):
        N = int(rng.integers(2, 60))
        w = _weights(rng, N)
        c = np.bincount(stratified(w, rng), minlength=N)
        assert np.all(c >= np.floor(N * w - 1e-9) - 1) and np.all(c <= np.ceil(N * w + 1e-9) + 1)


def test_residual_keeps_the_deterministic_copies():
    rng = np.random.default_rng(3)
    for _ in range(200):
        N = int(rng.integers(2, 60))
        w = _weights(rng, N)
        c = np.bincount(residual(w, rng), minlength=N)
        assert c.sum() == N and np.all(c >= np.floor(N * w - 1e-9))


@pytest.mark.parametrize("scheme", SCHEMES)
def test_resampling_unbiased(scheme):
    """E[count_i] = N w_i; the count variance of every scheme is at most the multinomial's, N w (1 - w)."""
    rng = np.random.default_rng(4)
    N, R = 20, 4000
    w = _weights(np.random.default_rng(5), N)
    counts = np.array([np.bincount(resample(w, rng, scheme), minlength=N) for _ in range(R)])
    se = np.sqrt(N * w * (1 - w) / R)
    assert np.all(np.abs(counts.mean(axis=0) - N * w) <= 5 * se + 1e-9)
    if scheme == "multinomial":  # the law itself: Binomial(N, w_i) marginals
        assert np.allclose(counts.var(axis=0), N * w * (1 - w), rtol=0.15, atol=0.01)


def test_multinomial_function_matches_dispatch():
    w = _weights(np.random.default_rng(6), 30)
    assert np.array_equal(multinomial(w, np.random.default_rng(1)), resample(w, np.random.default_rng(1), "multinomial"))


def _pf_run(model, pf, rng_data, steps):
    for _ in range(steps):
        pf.predict(U300, 1.0)
        x = np.mean(pf.X, axis=0)
        s, r = draw_sample(x, 100, rng_data)
        pf.update(s, r)


@pytest.mark.slow
def test_two_particle_filters_do_not_disturb_each_other(model):
    """Interleaved and separate runs give identical particles; numpy's global state is untouched."""
    st = FilterSettings(n_particles=100, ess_fraction=1.0)  # resample at every update

    def make():
        return (ParticleFilter(model, np.random.default_rng(11), st), np.random.default_rng(21),
                ParticleFilter(model, np.random.default_rng(12), st), np.random.default_rng(22))

    a1, da, b1, db = make()
    _pf_run(model, a1, da, 3)
    _pf_run(model, b1, db, 3)
    np.random.seed(7)
    before = np.random.get_state()
    a2, da2, b2, db2 = make()
    for _ in range(3):
        _pf_run(model, a2, da2, 1)
        _pf_run(model, b2, db2, 1)
    after = np.random.get_state()
    assert a1.n_resampled == 3 and b1.n_resampled == 3
    assert np.array_equal(a1.X, a2.X) and np.array_equal(a1.logP, a2.logP)
    assert np.array_equal(b1.X, b2.X) and np.array_equal(b1.logP, b2.logP)
    assert not np.array_equal(a1.X, b1.X)
    assert np.array_equal(before[1], after[1]) and before[2:] == after[2:]


# --- UKF: synthetic truth from the moment model and the stated laws ---------------------------
@pytest.fixture(scope="module")
def truth_path(model):
    """The moment model with gamma x1.3, delta x0.7 at 300 rpm: the state after each of 12 hours."""
    x, out = model.x0(), []
    for _ in range(12):
        x = model.step(x, U300, 1.0, P_TRUE)
        out.append(x.copy())
    return np.array(out)


def _synthetic_run(model, truth: np.ndarray, seed: int, n: int = 300):
    """The UKF on hourly samples of n particles drawn from the stated laws of the true states,
    and a temperature reading with the stated noise (2 degC)."""
    rng = np.random.default_rng(seed)
    f = UKFEstimator(model)
    ests = []
    for x in truth:
        s, r = draw_sample(x, n, rng)
        f.predict(U300, 1.0)
        ests.append(f.update(s, r, temperature_c=float(x[4] + 2.0 * rng.standard_normal())))
    return ests, f


@pytest.mark.slow
def test_ukf_tracks_moments_and_factors(model, truth_path):
    """Errors within the sampling error of n = 300 particles, 90 % intervals cover at >= 80 %.

    Bounds: the standard error of ln(sample mean) is cv / sqrt(n) ~ 0.55 / sqrt(300) = 0.032;
    the RMS error of every log moment must stay below 0.06 (2x, the other moments' sampling
    errors are of the same order), no single error above 0.2.
    """
    errs, hits, p_hits, p_err, widths = [], [], [], [], []
    truth = truth_path
    for seed in range(8):
        ests, f = _synthetic_run(model, truth, seed)
        mean = np.array([e.mean for e in ests])
        lo, hi = np.array([e.q05 for e in ests]), np.array([e.q95 for e in ests])
        errs.append(np.abs(np.log(mean[:, :4] / truth[:, :4])))
        hits.append((lo[:, :4] <= truth[:, :4]) & (truth[:, :4] <= hi[:, :4]))
        widths.append(np.log(hi[:, 0] / lo[:, 0]))
        p_hits.append((lo[-1, 6:8] <= P_TRUE) & (P_TRUE <= hi[-1, 6:8]))
        p_err.append(np.abs(np.log(mean[-1, 6:8] / P_TRUE)))
        assert f.n_repaired == 0
    errs = np.concatenate(errs)
    rms = np.sqrt(np.mean(errs**2, axis=0))
    assert np.all(rms < 0.06), rms
    assert errs.max() < 0.2
    cover = np.mean(np.concatenate(hits), axis=0)
    assert np.all(cover >= 0.8), cover
    assert np.median(np.concatenate(widths)) < 0.3  # not covering by being vacuous: s_mean within ~ +-15 %
    assert np.mean(p_hits) >= 0.8
    assert np.all(np.mean(p_err, axis=0) < 0.15), np.mean(p_err, axis=0)  # gamma, delta learnt from 1.0 start


@pytest.mark.slow
def test_ukf_state_round_trip_continues_identically(model, truth_path):
    rng = np.random.default_rng(3)
    data = [(draw_sample(x, 100, rng), float(x[4])) for x in truth_path[:6]]
    a = UKFEstimator(model)
    for (s, r), T in data[:3]:
        a.predict(U300, 0.5)
        a.predict(U300, 0.5)
        a.update(s, r, T)
    a.predict(U300, 0.25)  # pending noise carried over
    state = a.get_state()
    for v in state.values():
        assert isinstance(v, (np.ndarray, float, int))
    b = UKFEstimator(model)
    b.set_state({k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in state.items()})
    c = pickle.loads(pickle.dumps(a))  # trial checkpoints pickle the estimator
    for f in (a, b, c):
        f.predict(U300, 0.75)
    for (s, r), T in data[3:]:
        outs = [f.update(s, r, T) for f in (a, b, c)]
        for o in outs[1:]:
            assert np.array_equal(o.mean, outs[0].mean) and np.array_equal(o.q95, outs[0].q95)
        for f in (a, b, c):
            f.predict(U300, 1.0)
    assert np.array_equal(a.cov, b.cov) and np.array_equal(a.cov, c.cov)


def test_ukf_set_state_rejects_bad_data(model):
    f = UKFEstimator(model)
    good = f.get_state()
    for bad in ({**good, "z": np.zeros(3)}, {**good, "P": np.full((8, 8), np.nan)}, {k: v for k, v in good.items() if k != "q"}):
        with pytest.raises(ValueError):
            f.set_state(bad)


@pytest.mark.parametrize("bad", [{"alpha": 0.0}, {"alpha": 1.5}, {"process_noise_per_sqrt_h": (0.1, 0.1, 0.1)},
                                 {"process_noise_per_sqrt_h": (0.1, 0.1, 0.1, -0.1)}, {"kappa": -9.0},
                                 {"adapt_rate": 0.0}, {"learning_rate": 1.5}, {"law": {"size_law": "gamma"}},
                                 {"process_noise_floor": (2.0, 2.0, 2.0, 2.0)}, {"n_particles": 100},
                                 {"sigma_temperature_c": float("nan")}])
def test_ukf_settings_reject_bad_values(bad):
    with pytest.raises(ValidationError):
        UKFSettings(**bad)
    with pytest.raises(InputError, match="ukf.toml"):
        validate(UKFSettings, bad, "ukf.toml")


def test_make_pd_repairs_and_keeps():
    A = np.array([[1.0, 0.5], [0.5, 2.0]])
    P, rep = make_pd(A.copy())
    assert not rep and np.array_equal(P, A)
    bad = np.array([[1.0, 1.0 + 1e-7], [1.0 - 1e-7, 1.0 - 1e-9]])  # asymmetric, indefinite by round-off
    P, rep = make_pd(bad)
    assert rep and np.allclose(P, P.T) and np.all(np.linalg.eigvalsh(P) > 0)
    assert np.allclose(P, 0.5 * (bad + bad.T), atol=1e-6)


@pytest.mark.slow
def test_ukf_keeps_bounds_and_repairs_under_extreme_input(model):
    f = UKFEstimator(model, settings=UKFSettings(param_prior_log_std=3.0))
    for _ in range(5):
        f.predict((600.0, 1.0), 2.0)
    s = np.full(50, 2.0) * np.exp(np.random.default_rng(0).normal(0, 0.01, 50))
    e = f.update(s, np.full(50, 0.89), temperature_c=30.0)
    assert np.all(np.isfinite(e.mean)) and np.all(np.isfinite(f.cov))
    assert np.all(np.linalg.eigvalsh(f.cov) > 0)
    assert 0 < e.mean[2] <= 0.9 and 0 <= e.mean[5] <= 1
    assert np.all(e.mean[6:8] <= 20.0 * np.exp(0.5 * np.diag(f.cov)[6:8]) + 1e-9)


def test_make_estimator_kinds(model):
    assert isinstance(make_estimator("ukf", model, np.random.default_rng(0)), UKFEstimator)
    pf = make_estimator("pf", model, np.random.default_rng(0), n_particles=123)
    assert isinstance(pf, ParticleFilter) and pf.X.shape[0] == 123
    with pytest.raises(InputError, match="kind: the estimator is one of pf, ukf"):
        make_estimator("ekf", model, np.random.default_rng(0))


# --- selection: scenarios and the CLI --------------------------------------------------------
def _scenario(tmp_path, kind: str) -> str:
    text = (ROOT / "scenarios" / "trial-lab-recipe.toml").read_text(encoding="utf-8")
    text = text.replace('"models/', f'"{ROOT}/models/').replace('"controllers/', f'"{ROOT}/controllers/')
    p = tmp_path / f"sc-{kind}.toml"
    p.write_text(text + f'\n[estimator]\nkind = "{kind}"\n', encoding="utf-8")
    return str(p)


def test_scenario_estimator_kind(tmp_path):
    from bmctl.scenario import load_scenario

    assert load_scenario(_scenario(tmp_path, "ukf")).estimator.kind == "ukf"
    assert load_scenario(str(ROOT / "scenarios" / "trial-lab-recipe.toml")).estimator.kind == "pf"
    with pytest.raises(InputError, match="estimator.kind"):
        load_scenario(_scenario(tmp_path, "ekf"))


@pytest.mark.slow
def test_trial_runs_and_resumes_on_the_ukf(tmp_path):
    from bmctl.trial import run_trial

    sc = _scenario(tmp_path, "ukf")
    r = run_trial(sc, tmp_path / "a", seed=1, max_steps=2)
    assert r == {"interrupted_at_step": 2}
    run_trial(sc, tmp_path / "a", seed=1, resume=True, max_steps=2)
    rows = list(csv.DictReader((tmp_path / "a" / "trajectory.csv").read_text(encoding="utf-8").splitlines()))
    assert len(rows) == 4
    assert all(float(x["est_s_mean_um_q05"]) <= float(x["est_s_mean_um"]) <= float(x["est_s_mean_um_q95"]) for x in rows)
    b = run_trial(sc, tmp_path / "b", seed=1, max_steps=4)
    assert b == {"interrupted_at_step": 4}
    rows_b = list(csv.DictReader((tmp_path / "b" / "trajectory.csv").read_text(encoding="utf-8").splitlines()))
    for ra, rb in zip(rows, rows_b, strict=True):
        ra.pop("solve_ms"), rb.pop("solve_ms")  # wall-clock time
        assert ra == rb


@pytest.mark.slow
def test_cli_estimate_ukf(tmp_path, capsys, model):
    from bmctl.measure.tables import ParticleTable, write_table

    rng = np.random.default_rng(0)
    x = model.x0()
    folder = tmp_path / "samples"
    folder.mkdir()
    for k in range(2):
        x = model.step(x, U300, 1.0)
        s, r = draw_sample(x, 200, rng)
        write_table(folder / f"t{k + 1:02d}.csv", ParticleTable.from_size_aspect(s, r))
    out = tmp_path / "res" / "estimate.csv"
    rc = main(["estimate", LAB, "--samples", str(folder), "--times", "1,2", "--estimator", "ukf", "--out", str(out)])
    text, err = capsys.readouterr()
    assert rc == 0, err
    assert "unscented Kalman filter" in text
    rows = list(csv.DictReader(out.read_text(encoding="utf-8").splitlines()))
    assert [float(r["t_h"]) for r in rows] == [1.0, 2.0]
    for name in ("s_mean_um", "s_std_um", "r_mean", "r_std", "gamma_mult", "delta_mult"):
        for r in rows:
            assert float(r[f"{name}_q05"]) <= float(r[name]) <= float(r[f"{name}_q95"])
    rc = main(["estimate", LAB, "--samples", str(folder), "--times", "1,2", "--estimator", "kf", "--out", str(out)])
    assert rc == 2
    capsys.readouterr()
    out2 = tmp_path / "res2" / "estimate.csv"
    rc = main(["estimate", LAB, "--samples", str(folder), "--times", "1,2", "--estimator", "ukf",
               "--particles", "500", "--out", str(out2)])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "--particles: a particle count" in err, err
    assert not out2.parent.exists()
    rc = main(["estimate", LAB, "--samples", str(folder), "--times", "1,2", "--estimator", "ukf",
               "--seed", "3", "--out", str(out2)])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "--seed: seeds the particle filter" in err, err
    assert not out2.parent.exists()
