"""Propagation of the end band: filter particles through the moment model under a schedule.

``advise`` predicts the batch-end state of a weighted selection of filter particles
(:data:`bmctl.campaign.advice.BAND_PARTICLES`) under the planned schedule. The moment
model's numpy step (:meth:`bmctl.moments.model.MomentModel.step`) is batched over the
particles but pays numpy's per-operation overhead at every RKC stage (~0.13 s CPU per 0.5 h
interval); a 12 h schedule costs seconds.

This module evaluates the same step -- eqns (15)-(20) through :func:`bmctl.moments.equations.step`,
the same substeps and RKC stages -- as a casadi function compiled to C and cached on disk by
:mod:`bmctl.control.cache` (bmctl's own cache folder). The function *calls* the particle rate
field at every stage (as the MPC's compiled NLP does), so its C code is small and compiles in
seconds. The key is of the function's inputs (:func:`bmctl.control.cache.input_key`: the
model's constants and coefficients, the interval, substeps and stages, the generating modules'
source), so a process that finds the library builds nothing. While the library does not exist yet (the first process on a card), gcc runs in the
background and the numpy step is used; both evaluate the same equations, so the band agrees to
rounding (tests/campaign/test_campaign.py).
"""

from __future__ import annotations

import weakref

import numpy as np

_LOADED: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()  # model -> {dt: loaded Function}


class _Generator:
    """Adapter: :func:`bmctl.control.cache.start_compile` generates through ``generate_dependencies``."""

    def __init__(self, fn):
        self.fn = fn

    def generate_dependencies(self, name: str, opts: dict) -> None:
        import hashlib
        import os

        # casadi wants a C identifier as the generated file's stem; the cache's temporary name may hold
        # a '.' (the interval length), so generate under a safe stem and move the file to ``name``
        safe = "band_" + hashlib.sha256(name.encode()).hexdigest()[:16]
        os.replace(self.fn.generate(safe, opts), name)


def step_function(model, dt_h: float):
    """casadi.Function ``F(x[6], u[2], p[2]) -> x_next[6]``: :meth:`MomentModel.step` over ``dt_h``
    hours (default substeps and stages) with the rate field as a called function."""
    import casadi as ca

    from ..moments import equations as eq
    from ..moments.model import _ca_cols

    n, stages = model._integration(float(dt_h))
    R = model.rate_function()

    def rates(yl, T, h, w, bm, fm):
        v = R(ca.vertcat(*yl[:4]), ca.vertcat(T, h, w, bm, fm))
        return [v[i] for i in range(4)]

    x, u, p = ca.MX.sym("x", 6), ca.MX.sym("u", 2), ca.MX.sym("p", 2)
    out = eq.step(eq.CA(), model.const, model.coeffs, _ca_cols(x, 6), _ca_cols(u, 2), _ca_cols(p, 2),
                  float(dt_h), n, stages, rates=rates)  # eqns (15)-(20), mill then rest
    return ca.Function("band_step", [x, u, p], [ca.vertcat(*out)], ["x", "u", "p"], ["x_next"])


def compiled_step(model, dt_h: float):
    """The compiled :func:`step_function` from bmctl's cache, or None (not compiled yet: gcc is
    started in the background, or waited for with ``BMCTL_MPC_COMPILE=wait``; no gcc or cache)."""
    from ..control import cache

    if not cache.enabled():
        return None
    loaded = _LOADED.setdefault(model, {})
    key = round(float(dt_h), 12)
    if key in loaded:
        return loaded[key]
    n, stages = model._integration(float(dt_h))
    # keyed by what the function is built from, so a hit builds nothing symbolic
    inputs = {"model": cache.model_inputs(model), "dt_h": float(dt_h), "substeps": n, "stages": stages}
    path = cache.library_path(cache.input_key("band-step", inputs), prefix="band")
    if path is None:
        return None
    if not cache.ready(path):
        cache.start_compile(_Generator(step_function(model, dt_h)), path, wait=cache.wait_for_compile())
        if not cache.ready(path):
            return None
    import casadi as ca

    try:
        lib = ca.external("band_step", str(path))
        if [lib.size_in(i) for i in range(3)] + [lib.size_out(0)] != [(6, 1), (2, 1), (2, 1), (6, 1)]:
            raise RuntimeError("sizes do not fit")
    except Exception as exc:  # noqa: BLE001 - casadi raises RuntimeError on any bad library
        cache.notice(f"compiled band step {path.name} did not load ({str(exc).splitlines()[0][:80]}): rebuilt")
        path.unlink(missing_ok=True)
        return None
    loaded[key] = lib
    return lib


def propagate(model, X: np.ndarray, P: np.ndarray, schedule: list[dict]) -> np.ndarray:
    """States of the particles ``X`` (n, 6) with parameters ``P`` (n, 2) after the schedule's rows.

    Parameters
    ----------
    model : MomentModel
    X, P : ndarray
        Particle states and parameter multipliers (one row each).
    schedule : list of dict
        Rows with ``t0_h, t1_h, rpm, milling`` (:func:`bmctl.campaign.advice._schedule`).

    Returns
    -------
    ndarray, (n, 6)
    """
    X = np.asarray(X, dtype=float)
    P = np.asarray(P, dtype=float)
    fns: dict[float, object] = {}
    for row in schedule:
        dt = row["t1_h"] - row["t0_h"]
        u = np.array([row["rpm"], row["milling"]], dtype=float)
        k = round(dt, 12)
        if k not in fns:
            lib = compiled_step(model, dt)
            fns[k] = None if lib is None else lib.map(X.shape[0])
        F = fns[k]
        if F is None:
            X = np.asarray(model.step(X, u, dt, P))
        else:
            X = np.asarray(F(X.T, u, P.T), dtype=float).T
    return X
