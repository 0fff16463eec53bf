"""Estimator: likelihood vs scipy.stats, seeded resampling, filter health and coverage, `bmctl estimate`."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from scipy import integrate, stats

from bmctl.cli import main
from bmctl.estimate import likelihood as L
from bmctl.estimate.filter import FilterSettings, ParticleFilter
from bmctl.estimate.resampling import SCHEMES, effective_sample_size, resample
from bmctl.validation import study as S

from ..conftest import ROOT

from ..conftest import card_path

LAB = str(card_path("alni-1to1-300rpm-lab"))


@pytest.fixture(scope="module")
def model():
    from bmctl.moments.model import make_moment_model

    return make_moment_model(LAB)


# --- likelihood ------------------------------------------------------------------------------
def _states(rng, k=5):
    m = rng.uniform(10, 80, k)
    return m, m * rng.uniform(0.2, 0.9, k), rng.uniform(0.02, 0.3, k), rng.uniform(0.02, 0.15, k)


def test_continuous_loglik_matches_scipy():
    rng = np.random.default_rng(0)
    s = rng.lognormal(3.5, 0.5, 200)
    r = rng.beta(0.8, 6.0, 200)
    stats_ = L.SampleStats.from_particles(s, r)
    ms, ss, mr, sr = _states(rng)
    got_s = L.loglik_size(stats_, ms, ss, 0.0)
    got_r = L.loglik_aspect(stats_, mr, sr, 0.0)
    rc = np.clip(r, L.R_FLOOR, 1 - L.R_FLOOR)
    for k in range(ms.size):
        mu, sig = L.lognormal_params(ms[k], ss[k])
        ref_s = stats.lognorm(s=sig, scale=np.exp(mu)).logpdf(s).sum()
        a, b = L.beta_params(mr[k], sr[k])
        ref_r = stats.beta(a, b).logpdf(rc).sum()
        assert got_s[k] == pytest.approx(ref_s, rel=1e-10)
        assert got_r[k] == pytest.approx(ref_r, rel=1e-9)
        # the laws have the state's moments
        assert stats.lognorm(s=sig, scale=np.exp(mu)).mean() == pytest.approx(ms[k], rel=1e-12)
        assert stats.beta(a, b).std() == pytest.approx(sr[k], rel=1e-9)
    # measurement noise widens the log-variance exactly
    mu, sig = L.lognormal_params(ms[0], ss[0])
    ref = stats.norm(mu, np.hypot(sig, 0.1)).logpdf(np.log(s)).sum() - np.log(s).sum()
    assert L.loglik_size(stats_, ms[:1], ss[:1], 0.1)[0] == pytest.approx(ref, rel=1e-10)


@pytest.mark.parametrize("size_law", ["lognormal", "weibull"])
def test_raster_size_cells_match_scipy_cdf(size_law):
    rng = np.random.default_rng(1)
    s = rng.lognormal(3.5, 0.6, 300)
    law = L.LawSettings(size_law=size_law, sigma_log_s=0.0)
    R = L.Raster.from_particles(s, np.zeros_like(s), law)
    assert R.s_counts.sum() == 300 and R.r_zero == 300
    ms, ss, _, _ = _states(rng)
    got = L.size_cell_logp(R, ms, ss, law)
    e = np.exp(R.s_edges())
    for k in range(ms.size):
        if size_law == "lognormal":
            mu, sig = L.lognormal_params(ms[k], ss[k])
            dist = stats.lognorm(s=sig, scale=np.exp(mu))
        else:
            kk, lnlam = L.weibull_params(ms[k], ss[k])
            dist = stats.weibull_min(kk, scale=np.exp(lnlam))
            # the tabulated shape gives the state's moments (table interpolation: 1e-4)
            assert dist.mean() == pytest.approx(ms[k], rel=1e-4) and dist.std() == pytest.approx(ss[k], rel=1e-3)
        ref = np.log(np.maximum(np.diff(dist.cdf(e)), 1e-300))
        ok = ref > -30  # deep-tail cells: scipy's cdf differences lose all digits there
        np.testing.assert_allclose(got[k][ok], ref[ok], rtol=1e-6, atol=1e-8)


@pytest.mark.slow
def test_raster_shape_cells_match_noisy_beta_integral():
    """P(cell) = int Beta(r) [Phi((hi-r)/s) - Phi((lo-r)/s)] dr, and P(r_meas = 0) = int Beta(r) Phi(-r/s) dr.

    Reference: the integrals after the substitution r = u^(1/a), which removes the r^(a-1)
    singularity (the integrand becomes (1 - r)^(b-1) / (a B(a, b)) times the kernel), by
    Simpson's rule on 200,001 points in u (checked against scipy.integrate.quad to 1e-6).
    The raster puts the Beta mass of 0.01-wide true-r cells at their midpoints (exact mass and
    mean for the 4 cells near 0, where a < 1 makes the density singular); with noise 0.034
    (3.4 cells) that is good to 0.4 % of each cell probability, 1.9 % in the extreme a = 0.1
    case (checked at 2.5 %, for cells holding >= 1e-3 of the mass).
    """
    from scipy.special import betaln, ndtr

    law = L.LawSettings()
    r = np.concatenate([[0.0], (np.arange(60) + 0.5) * 0.01])  # the atom and every cell up to 0.6
    R = L.Raster.from_particles(np.full(r.size, 30.0), r, law)
    u = np.linspace(0.0, 1.0, 200_001)
    sig = law.sigma_r
    for mean, std in ((0.01, 0.03), (0.05, 0.08), (0.15, 0.12), (0.3, 0.15)):
        a, b = L.beta_params(mean, std)
        got = np.exp(L.shape_cell_logp(R, np.array([mean]), np.array([std]), law)[0])
        x = u ** (1.0 / a)
        dens = np.exp((b - 1) * np.log1p(-np.minimum(x, 1 - 1e-16)) - np.log(a) - betaln(a, b))
        kern = [ndtr(-x / sig)]
        for j in R.r_cells:
            lo, hi = j * 0.01, (j + 1) * 0.01
            kern.append(ndtr((hi - x) / sig) - ndtr((lo - x) / sig))
        refs = integrate.simpson(dens[None, :] * np.array(kern), x=u, axis=1)
        if mean == 0.05:  # the reference itself, against adaptive quadrature, for two cells
            beta = stats.beta(a, b)
            q0 = integrate.quad(lambda v: beta.pdf(v) * stats.norm.cdf(-v / sig), 0, 1, limit=200, points=[1e-6, 1e-3])[0]
            assert refs[0] == pytest.approx(q0, rel=1e-6)
        big = refs > 1e-3
        np.testing.assert_allclose(got[big], refs[big], rtol=0.025)
        assert got.sum() == pytest.approx(refs.sum(), abs=5e-3)


def test_fit_sample_recovers_a_well_specified_sample():
    """Data drawn from the filter's own laws: the fit is within 4 standard errors and eta ~ 1."""
    rng = np.random.default_rng(3)
    law = L.LawSettings(size_law="weibull")
    truth = np.array([40.0, 20.0, 0.12, 0.10])
    kk, lnlam = L.weibull_params(truth[0], truth[1])
    n = 2000
    s = np.exp(lnlam) * rng.weibull(kk, n) * np.exp(law.sigma_log_s * rng.standard_normal(n))
    a, b = L.beta_params(truth[2], truth[3])
    r = np.clip(rng.beta(a, b, n) + law.sigma_r * rng.standard_normal(n), 0.0, 0.999)
    fit = L.fit_sample(L.Raster.from_particles(s, r, law), law)
    assert fit.ok.all()
    se = 1 / np.sqrt(np.diag(fit.info))
    assert np.all(np.abs(fit.z - np.log(truth)) < 4 * se), (np.exp(fit.z), se)
    assert np.all(fit.eta > 0.8)


def test_loglik_raster_is_finite_for_impossible_states():
    law = L.LawSettings()
    R = L.Raster.from_particles([10.0, 500.0], [0.0, 0.9], law)
    ls, lr = L.loglik_raster(R, np.array([1e4, 0.2]), np.array([1.0, 0.01]), np.array([0.9, 1e-4]),
                             np.array([1e-4, 1e-4]), law)
    assert np.all(np.isfinite(ls)) and np.all(np.isfinite(lr))


# --- resampling ------------------------------------------------------------------------------
@pytest.mark.parametrize("scheme", SCHEMES)
def test_resampling_reproducible_and_leaves_global_state(scheme):
    w = np.random.default_rng(5).random(500)
    w /= w.sum()
    np.random.seed(1234)
    before = np.random.get_state()
    a = resample(w, np.random.default_rng(9), scheme)
    b = resample(w, np.random.default_rng(9), scheme)
    c = resample(w, np.random.default_rng(10), scheme)
    after = np.random.get_state()
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert before[0] == after[0] and np.array_equal(before[1], after[1]) and before[2:] == after[2:]
    assert a.min() >= 0 and a.max() < w.size and a.size == w.size
    # frequencies follow the weights (all schemes are unbiased)
    counts = np.bincount(np.concatenate([resample(w, np.random.default_rng(k), scheme) for k in range(40)]),
                         minlength=w.size)
    assert np.corrcoef(counts, w)[0, 1] > 0.9
    assert effective_sample_size(np.full(10, 0.1)) == pytest.approx(10.0)


# --- filter ----------------------------------------------------------------------------------
@pytest.mark.slow
def test_filter_short_run_is_healthy_and_covers_truth(model):
    """Plant truth (lab card, M = 2000), 4 hourly samples of 300 particles, N = 500 filter particles."""
    from bmctl.config import load_card

    card = load_card(LAB)
    cfg = S.StudyConfig(card=LAB, hours=4.0, plant_particles=2000, filter_particles=500,
                        variants=(S.Variant(300),))
    run = S.run_one(model, card, (1.0, 1.0), 11, cfg)
    rec = run["weibull-n300"]
    for k in ("mean", "q05", "q95", "ess"):
        assert np.all(np.isfinite(rec[k]))
    assert np.all((rec["ess"] > 0.05 * 500) & (rec["ess"] <= 500 + 1e-6))  # no collapse
    lo, hi, tr = rec["q05"][-1, :4], rec["q95"][-1, :4], run["truth"][-1, :4]
    covered = (lo <= tr) & (tr <= hi)
    assert covered[0] and covered[2], (lo, hi, tr)  # s_mean and r_mean at the end
    assert covered.sum() >= 3
    assert np.all(np.abs(np.log(rec["mean"][-1, :4] / tr)) < 0.25)


@pytest.mark.slow
def test_filter_update_guards(model):
    pf = ParticleFilter(model, np.random.default_rng(0), FilterSettings(n_particles=200))
    pf.predict((300.0, 1.0), 1.0)
    est = pf.update(np.full(20, 1e4), np.full(20, 0.95))  # a sample no state can explain
    assert np.all(np.isfinite(pf.weights)) and np.all(np.isfinite(est.mean)) and est.ess >= 1
    est = pf.update(temperature_c=60.0)  # a temperature reading alone
    assert np.isfinite(est.ess)
    pf.predict((0.0, 0.0), 0.5)
    est = pf.estimate()  # read without an update: deferred noise applied, still finite
    assert np.all(np.isfinite(est.mean)) and pf.pending_h == 0.0


@pytest.mark.slow
def test_small_coverage_study(model):
    """3 seeds x 2 off-card scenarios x 6 hourly samples (n = 300): 36 (run, time) pairs per moment.

    Nominal 90 % intervals; pairs within a run are correlated, so the binomial sd (0.05) is
    an underestimate. The threshold 0.65 fails a systematic miss (the log-normal law's s_std
    coverage is < 0.1 here) while passing sampling noise.
    """
    cfg = S.StudyConfig(card=LAB, seeds=(0, 1, 2), hours=6.0, plant_particles=2000, filter_particles=500,
                        variants=(S.Variant(300),))
    res = S.run_study(cfg)
    cov = np.mean([S.coverage(runs, "weibull-n300") for runs in res.values()], axis=0)
    assert np.all(cov >= 0.65), cov


# --- CLI -------------------------------------------------------------------------------------
def _write_samples(folder, n_samples=2, n=200, seed=0):
    from bmctl.measure.tables import ParticleTable, write_table
    from bmctl.plant import make_plant
    from bmctl.plant.population import UM

    folder.mkdir(parents=True, exist_ok=True)
    plant = make_plant(LAB, seed=seed, particles=1000)
    rng = np.random.default_rng(seed)
    paths = []
    for k in range(n_samples):
        plant.advance(300.0, 1.0)
        idx = rng.integers(0, plant.M, n)
        p = folder / f"t{k + 1:02d}.csv"
        write_table(p, ParticleTable.from_size_aspect(plant.s[idx] / UM, plant.r[idx]))
        paths.append(p)
    return paths


@pytest.mark.slow
def test_cli_estimate_writes_csv_and_figure(tmp_path, capsys):
    _write_samples(tmp_path / "samples")
    out = tmp_path / "res" / "estimate.csv"
    rc = main(["estimate", LAB, "--samples", str(tmp_path / "samples"), "--times", "1,2", "--particles", "200",
               "--out", str(out), "--temperatures", "60,"])
    _, err = capsys.readouterr()
    assert rc == 0, err
    rows = list(csv.DictReader(out.read_text(encoding="utf-8").splitlines()))
    assert [float(r["t_h"]) for r in rows] == [1.0, 2.0]
    for name in ("s_mean_um", "s_std_um", "r_mean", "r_std", "temperature_c", "hardening", "gamma_mult", "delta_mult"):
        for r in rows:
            assert float(r[f"{name}_q05"]) <= float(r[name]) <= float(r[f"{name}_q95"])
    assert all(0 < float(r["ess"]) <= 200 for r in rows)
    assert (tmp_path / "res" / "estimate.png").read_bytes()[:4] == b"\x89PNG"


def _bad_table(tmp_path, text, name="bad.csv"):
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return str(p)


@pytest.mark.parametrize("case", ["missing", "empty", "header-only", "nan", "count", "negative", "unknown-flag",
                                  "not-a-number", "decreasing", "repeated", "empty-dir", "bad-schedule", "rpm"])
def test_cli_estimate_bad_input(tmp_path, capsys, case):
    good = [str(p) for p in _write_samples(tmp_path / "ok")]
    out = tmp_path / "o" / "estimate.csv"
    args = {
        "missing": ["--samples", str(tmp_path / "nope.csv"), "--times", "1"],
        "empty": ["--samples", _bad_table(tmp_path, ""), "--times", "1"],
        "header-only": ["--samples", _bad_table(tmp_path, "s_um,r\n"), "--times", "1"],
        "nan": ["--samples", _bad_table(tmp_path, "s_um,r\n10,0.1\nnan,0.2\n"), "--times", "1"],
        "count": ["--samples", *good, "--times", "1"],
        "negative": ["--samples", good[0], "--times=-1"],
        "unknown-flag": ["--samples", good[0], "--times", "1", "--bogus"],
        "not-a-number": ["--samples", good[0], "--times", "one"],
        "decreasing": ["--samples", *good, "--times", "2,1"],
        "repeated": ["--samples", *good, "--times", "1,1"],  # non-increasing (docs/estimation.md), was filtered
        "empty-dir": ["--samples", str((tmp_path / "void").resolve()), "--times", "1"],
        "bad-schedule": ["--samples", *good, "--times", "1,2", "--schedule", _bad_table(tmp_path, "[[segment]]\nhours = 1\nrpm = 300\n", "s.toml")],
        "rpm": ["--samples", good[0], "--times", "1", "--rpm", "9000"],
    }[case]
    if case == "empty-dir":
        (tmp_path / "void").mkdir()
    rc = main(["estimate", LAB, *args, "--out", str(out), "--particles", "100"])
    _, err = capsys.readouterr()
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("bmctl: error: "), err
    assert not out.exists() and not out.with_suffix(".png").exists()


def test_write_card_refuses_an_existing_file_unless_forced(tmp_path, capsys):
    """--write-card onto an existing, unrelated .toml (a schedule here) replaced it without a word: now it
    is refused in one line before any work, nothing written; --force replaces it with the card."""
    from bmctl.config import load_card

    sample = str(ROOT / "examples" / "samples" / "lab-300rpm-0p5h.csv")
    other = tmp_path / "mine.toml"
    other.write_text('name = "my schedule"\n\n[[segment]]\nhours = 2\nrpm = 300\n', encoding="utf-8")
    before = other.read_bytes()
    args = ["estimate", LAB, "--samples", sample, "--times", "0.5", "--particles", "100",
            "--out", str(tmp_path / "w.csv"), "--write-card", str(other), "--no-progress"]
    rc = main(args)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert err[0] == (f"bmctl: error: --write-card: {other} exists; give --force to replace it, or choose another "
                      "file name")
    assert other.read_bytes() == before and not (tmp_path / "w.csv").exists()
    assert main(args + ["--force"]) == 0
    assert "wrote " + str(other) in capsys.readouterr().out
    assert load_card(other).card.name == "alni-1to1-300rpm-lab-calibrated"


def test_force_without_write_card_is_refused(tmp_path, capsys):
    rc = main(["estimate", LAB, "--samples", str(ROOT / "examples" / "samples" / "lab-300rpm-0p5h.csv"),
               "--times", "0.5", "--out", str(tmp_path / "w.csv"), "--force"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "--force: only with --write-card" in err[0], err
    assert not (tmp_path / "w.csv").exists()


@pytest.mark.parametrize("dest, why", [("w.csv", "expected a .toml"), ("card", "an input or output of this run")])
def test_write_card_never_replaces_an_input_or_output(tmp_path, capsys, dest, why):
    """--write-card onto the table, a sample or the card itself once replaced it without a word."""
    import shutil

    from bmctl.cli import main

    card = tmp_path / "card.toml"
    shutil.copy(ROOT / "models" / "alni-1to1-300rpm-lab.toml", card)
    shutil.copy(ROOT / "models" / "alni-1to1-300rpm-lab.moments.toml", tmp_path / "card.moments.toml")
    before = card.read_bytes()
    target = card if dest == "card" else tmp_path / dest
    rc = main(["estimate", str(card), "--samples", str(ROOT / "examples" / "samples"), "--times", "0.5,1,2,4,8",
               "--particles", "200", "--out", str(tmp_path / "w.csv"), "--write-card", str(target), "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and why in err[0], err
    assert card.read_bytes() == before and not (tmp_path / "w.csv").exists()


def test_cli_estimate_warns_of_a_sample_outside_the_cards_size_range(tmp_path, capsys):
    """A table in mm read as µm was filtered without a word (the update's ESS stayed just above the
    degenerate limit, its band a clamp at 0.1 µm); it is now named on stderr, as `bmctl simulate`
    names a run outside the card's range of validity."""
    good = [str(p) for p in _write_samples(tmp_path / "ok")]
    mm = tmp_path / "mm.csv"
    mm.write_text("s_um,r\n" + "".join(f"{0.04 + 0.001 * k:g},0.2\n" for k in range(30)), encoding="utf-8")
    rc = main(["estimate", LAB, "--samples", good[0], str(mm), "--times", "1,2", "--particles", "100",
               "--out", str(tmp_path / "e.csv"), "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 0
    warns = [ln for ln in err.splitlines() if "outside the card's" in ln]
    assert len(warns) == 1 and "mm.csv" in warns[0] and "at 2 h" in warns[0], err


def test_the_first_readings_prediction_counts_the_heating_gains_prior(model):
    """Before the first reading every particle heats as the card says (gain 1): the particles' spread
    of the vial temperature is nil, and a reading 20 % off the card's heating was called '6 σ far'.
    The reading will weigh in the gain's prior N(1, 0.3^2) and its walk, so its predicted sd is that
    share of the card law's excess over ambient (eqn 7 in closed form, 0.5 h at 400 rpm from ambient);
    once spent, the prediction narrows to what the reading taught."""
    import math

    from bmctl.campaign.mill import predicted_temperature
    from bmctl.campaign.readings import reading_warnings
    from bmctl.config import load_card
    from bmctl.plant.kinematics import kinematics

    card = load_card(LAB)
    st = FilterSettings(n_particles=200)
    pf = ParticleFilter(model, np.random.default_rng(0), st)
    pf.predict([400.0, 1.0], 0.5)
    th = card.thermal
    excess = (kinematics(card, 400.0).mean_power_W * th.cooling_time_s / th.heat_capacity_J_per_K
              * (1 - math.exp(-1800.0 / th.cooling_time_s)))
    m, sd = predicted_temperature(pf)
    assert m == pytest.approx(th.ambient_C + excess, rel=1e-6)
    assert sd == pytest.approx(math.hypot(st.thermal_gain_prior_std, st.thermal_gain_walk_per_sqrt_h
                                          * math.sqrt(0.5)) * excess, rel=1e-3)
    y = th.ambient_C + 0.8 * excess  # a mill heating 20 % less than its card
    est = {"t_h": 0.5, "reading_c": y, "reading_predicted_c": m, "reading_predicted_sd_c": sd}
    assert not any("far from" in w for w in reading_warnings(est, 200.0, st.sigma_temperature_c, th.ambient_C))
    pf.update(temperature_c=y)
    pf.predict([400.0, 1.0], 0.5)
    assert predicted_temperature(pf)[1] < 0.25 * sd
