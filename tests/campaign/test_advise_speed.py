"""Fast fresh-process advise: cached model constants, compiled end band, same advice as in-process."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bmctl import campaign as cp
from bmctl.campaign import band
from bmctl.moments.modelcache import moment_model
from bmctl.measure.tables import ParticleTable
from bmctl.moments.model import make_moment_model

ROOT = Path(__file__).resolve().parents[2]
CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
MPC = ROOT / "controllers" / "mpc-default.toml"


@pytest.fixture
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setenv("BMCTL_MPC_COMPILE", "wait")
    return tmp_path / "cache" / "bmctl" / "mpc"


@pytest.mark.slow
def test_cached_model_equals_a_fresh_build(tmp_path, private_cache):
    """The model restored from the cache has the same attributes, constants, coefficients and steps;
    a damaged entry is rebuilt."""
    card = tmp_path / CARD.name
    shutil.copyfile(CARD, card)
    fresh = make_moment_model(card)
    first = moment_model(card)
    (entry,) = private_cache.glob("model-*.json")
    cached = moment_model(card)
    for m in (first, cached):
        assert vars(m).keys() == vars(fresh).keys()
        assert m.const == fresh.const and m.coeffs == fresh.coeffs and m.coeffs_source == fresh.coeffs_source
    x, u = fresh.x0(), np.array([400.0, 0.5])
    assert np.array_equal(cached.step(x, u, 0.5), fresh.step(x, u, 0.5))
    entry.write_text("{not json", encoding="utf-8")
    assert moment_model(card).const == fresh.const
    card.write_text(card.read_text(encoding="utf-8") + "\n# edited\n", encoding="utf-8")  # other bytes: another key
    moment_model(card)
    assert len(list(private_cache.glob("model-*.json"))) == 2


@pytest.mark.slow
def test_compiled_end_band_equals_the_numpy_step(private_cache):
    """The compiled band step evaluates MomentModel.step's equations: same states to rounding."""
    m = make_moment_model(CARD)
    rng = np.random.default_rng(1)
    X = np.tile(m.x0(), (16, 1)) * rng.uniform(0.9, 1.1, (16, 6))
    P = rng.uniform(0.8, 1.2, (16, 2))
    sched = [{"t0_h": 0.5 * k, "t1_h": 0.5 * k + 0.5, "rpm": 500.0 - 20 * k, "milling": 0.4} for k in range(6)]
    sched.append({"t0_h": 3.0, "t1_h": 3.25, "rpm": 300.0, "milling": 1.0})  # a shorter last interval
    Xc = band.propagate(m, X, P, sched)
    assert band.compiled_step(m, 0.5) is not None and list(private_cache.glob("band-*.so"))
    Xn = X
    for r in sched:
        Xn = m.step(Xn, np.array([r["rpm"], r["milling"]]), r["t1_h"] - r["t0_h"], P)
    np.testing.assert_allclose(Xc, Xn, rtol=1e-10, atol=0)


@pytest.mark.slow
def test_fresh_process_advise_equals_in_process(tmp_path, private_cache):
    """An advise from a new process (cached model, compiled warm solver and band, state from the
    database) gives the advice of a campaign kept open, to solver tolerance."""
    d, d2 = tmp_path / "kept", tmp_path / "copy"
    cp.init(d, CARD, MPC, {"d50_um": 45.0}, hours=3.0, particles=100)
    rng = np.random.default_rng(0)
    with cp.Campaign(d) as c:
        a = cp.advise(d, campaign=c)
        cp.log(d, a["next"]["rpm"], 0.5, a["next"]["mill_min"] / 30.0, campaign=c)
        cp.sample(d, 0.5, [ParticleTable.from_size_aspect(rng.lognormal(np.log(50), 0.45, 200),
                                                          rng.uniform(0, 0.1, 200))], campaign=c)
        shutil.copytree(d, d2)
        kept = cp.advise(d, campaign=c)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-m", "bmctl", "campaign", "advise", str(d2), "--json"], cwd=ROOT, env=env,
                         check=True, capture_output=True, text=True).stdout
    fresh = json.loads(out)
    assert kept["solver_ok"] and fresh["solver_ok"]
    assert fresh["next"]["mill_min"] == kept["next"]["mill_min"]
    assert fresh["next"]["rpm"] == pytest.approx(kept["next"]["rpm"], rel=1e-4)
    for rk, rf in zip(kept["schedule"], fresh["schedule"]):
        assert rf["rpm"] == pytest.approx(rk["rpm"], rel=1e-4) and rf["mill_min"] == rk["mill_min"]
    for k, e in kept["end"].items():
        for q in ("q05", "median", "q95"):
            assert fresh["end"][k][q] == pytest.approx(e[q], rel=1e-4), (k, q)


def test_end_band_with_energy_mult_takes_the_numpy_step(monkeypatch):
    """Particles with a third multiplier (energy_mult) are not fed to the two-multiplier compiled
    step: the band is MomentModel.step's with all three (it crashed once the library existed)."""
    m = make_moment_model(CARD)
    monkeypatch.setattr(band, "compiled_step", lambda model, dt: band.step_function(model, dt))
    rng = np.random.default_rng(2)
    X = np.tile(m.x0(), (8, 1)) * rng.uniform(0.95, 1.05, (8, 6))
    P = np.column_stack([rng.uniform(0.8, 1.2, (8, 2)), np.full(8, 1.4)])
    sched = [{"t0_h": 0.0, "t1_h": 0.5, "rpm": 400.0, "milling": 0.5}]
    got = band.propagate(m, X, P, sched)
    want = m.step(X, np.array([400.0, 0.5]), 0.5, P)
    np.testing.assert_array_equal(got, want)
    assert not np.allclose(got[:, 0], m.step(X, np.array([400.0, 0.5]), 0.5, P[:, :2])[:, 0])
