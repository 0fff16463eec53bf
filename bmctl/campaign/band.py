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
source), so a process that finds the library builds nothing; the step is
:func:`bmctl.control.compiled.compiled_step`, which the MPC's initial guess uses too. While the
library does not exist yet (the first process on a card), gcc runs in the background and the
numpy step is used; both evaluate the same equations, so the band agrees to
rounding (tests/campaign/test_campaign.py). Particles that carry ``energy_mult`` (the campaign
filter's default) always take the numpy step.
"""

from __future__ import annotations

import numpy as np

from ..control.compiled import compiled_step, step_function  # the step lives with the MPC's

__all__ = ["compiled_step", "propagate", "step_function"]


def propagate(model, X: np.ndarray, P: np.ndarray, schedule: list[dict], substeps: int | None = None) -> np.ndarray:
    """States of the particles ``X`` (n, 6) with parameters ``P`` (n, 2) or (n, 3) after the schedule's rows.

    With ``substeps`` (a plan made on the operable grid: the substeps its search predicted with)
    the numpy step is used with that many RKC substeps per row, so the band and the plan come from
    the same prediction and nothing is compiled; else the compiled step when cached (see above).

    Parameters
    ----------
    model : MomentModel
    X, P : ndarray
        Particle states and parameter multipliers (one row each): ``gamma_mult, delta_mult`` and,
        when the filter learns it, ``energy_mult`` (then the numpy step: the compiled rate field
        takes the first two only).
    schedule : list of dict
        Rows with ``t0_h, t1_h, rpm, milling`` (:func:`bmctl.campaign.advice._schedule`).
    substeps : int, optional
        RKC substeps per row of the numpy step (:func:`bmctl.control.search.interval_step`), as the
        plan's search predicted with; None: the compiled step when cached, else the numpy step.

    Returns
    -------
    ndarray, (n, 6)
    """
    X = np.asarray(X, dtype=float)
    P = np.asarray(P, dtype=float)
    if substeps is not None:
        from ..control.search import interval_step

        n = X.shape[0]
        for row in schedule:
            L = (row["t1_h"] - row["t0_h"]) * 60.0
            a = float(row["milling"]) * L if row["rpm"] > 0 else 0.0
            X = interval_step(model, X, P, np.full(n, float(row["rpm"])), np.full(n, a), L, substeps)
        return X
    fns: dict[float, object] = {}
    two = P.ndim == 2 and P.shape[1] == 2  # the compiled step takes (gamma_mult, delta_mult) only
    for row in schedule:
        dt = row["t1_h"] - row["t0_h"]
        u = np.array([row["rpm"], row["milling"]], dtype=float)
        k = round(dt, 12)
        if k not in fns:
            lib = compiled_step(model, dt) if two else None
            fns[k] = None if lib is None else lib.map(X.shape[0])
        F = fns[k]
        if F is None:
            X = np.asarray(model.step(X, u, dt, P))
        else:
            X = np.asarray(F(X.T, u, P.T), dtype=float).T
    return X
