"""The vectorised numpy field (bmctl.moments.npfield) gives the node-by-node definition's numbers bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

import bmctl.moments.equations as eq
from bmctl.moments import make_moment_model

CARD = "models/alni-1to1-300rpm-lab.toml"


@pytest.fixture(scope="module")
def model():
    return make_moment_model(CARD)


@pytest.fixture
def generic(monkeypatch):
    """Run a callable with the node-by-node numpy definition (NP_VECTORISED off)."""

    def run(f, *a, **kw):
        monkeypatch.setattr(eq, "NP_VECTORISED", False)
        try:
            return f(*a, **kw)
        finally:
            monkeypatch.setattr(eq, "NP_VECTORISED", True)

    return run


def _bits(v):
    return np.asarray(v, dtype=float).view(np.int64)


def _states(model, rng, n):
    x = np.tile(model.x0(), (n, 1)) * rng.uniform(0.2, 3.0, (n, 6))
    x[:, 2] = rng.uniform(-0.1, 1.1, n)
    x[:, 3] = rng.uniform(-0.05, 0.5, n)
    x[:, 4] = rng.uniform(15, 120, n)
    x[:, 5] = rng.uniform(0, 1, n)
    return x


@pytest.mark.parametrize("variant", ["card", "no cv slopes", "one link"])
def test_rates_bit_identical(model, generic, variant):
    c, q = model.const, dict(model.coeffs)
    if variant != "card":
        q["r_link_cv_slope"] = q["frac_link_cv_shift"] = 0.0
    if variant == "one link":
        q["frac_link_shift"] = 0.0
    rng = np.random.default_rng(1)
    for n in (1, 7, 64):
        x = _states(model, rng, n)
        y = eq.to_y(eq.NP, [x[:, i] for i in range(6)])
        w = rng.uniform(0.0, 1.0, n)
        bm, fm = rng.uniform(0.2, 3, n), rng.uniform(0.2, 3, n)
        for ww in (w, 0.4):  # an array, and a plain number broadcast over the batch
            with np.errstate(all="ignore"):
                a = generic(eq.y_rates, eq.NP, c, q, y, x[:, 4], x[:, 5], ww, bm, fm)
                b = eq.y_rates(eq.NP, c, q, y, x[:, 4], x[:, 5], ww, bm, fm)
            for u, v in zip(a, b):
                assert u.shape == v.shape and np.array_equal(_bits(u), _bits(v))


def test_step_bit_identical(model, generic):
    c, q = model.const, model.coeffs
    rng = np.random.default_rng(2)
    for n, st, dt in ((1, 2, 0.5), (40, 5, 0.5), (33, 8, None)):
        x = _states(model, rng, n)
        x[:, 2] = rng.uniform(0.0, 0.6, n)
        x[:, 3] = rng.uniform(0.0, 0.3, n)
        us = [rng.uniform(100, 500, n), rng.uniform(0, 1, n)]
        ps = [rng.uniform(0.3, 2.5, n), rng.uniform(0.3, 2.5, n)]
        dt_h = rng.uniform(0.01, 0.6, n) if dt is None else dt
        xs = [x[:, i] for i in range(6)]
        with np.errstate(all="ignore"):
            a = generic(eq.step, eq.NP, c, q, xs, us, ps, dt_h, 2, st)
            b = eq.step(eq.NP, c, q, xs, us, ps, dt_h, 2, st)
        assert len(a) == len(b) == 6
        for u, v in zip(a, b):
            assert np.array_equal(_bits(u), _bits(v))


def test_model_step_bit_identical(model, generic):
    """The model's own step (filters, studies) on a 2-D batch falls back or matches, bit for bit."""
    rng = np.random.default_rng(3)
    X = np.tile(model.x0(), (5, 1)) * rng.uniform(0.9, 1.1, (5, 6))
    P = rng.uniform(0.5, 2.0, (5, 2))
    u = np.array([350.0, 0.5])
    a = generic(model.step, X, u, 0.5, P)
    b = model.step(X, u, 0.5, P)
    assert np.array_equal(_bits(a), _bits(b))


def test_fast_path_taken(model, monkeypatch):
    """A 1-D batch with a plain or 0-d input runs the vectorised step; a 2-D one the generic step."""
    import bmctl.moments.npfield as nf

    calls = []
    real = nf.step_np
    monkeypatch.setattr(nf, "step_np", lambda *a, **k: calls.append(1) or real(*a, **k))
    X = np.tile(model.x0(), (4, 1))
    model.step(X, np.array([300.0, 1.0]), 0.5)
    assert calls
    calls.clear()
    xs = [np.tile(X[:, i], (2, 1)) for i in range(6)]
    eq.step(eq.NP, model.const, model.coeffs, xs, [300.0, 1.0], [1.0, 1.0], 0.5, 2, 4)
    assert not calls
