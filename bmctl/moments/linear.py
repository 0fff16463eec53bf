"""Linear analysis of the moment model with python-control: linearisation, ranks, gramians, steps.

Jacobians come from casadi (exact derivatives of the same equations). States and inputs
are scaled by typical magnitudes before ranks and gramians are computed, so that the
conditioning reflects the physics, not the units (docs/moments.md, Sec. 5).
"""

from __future__ import annotations

import numpy as np

#: outputs a micrograph measures: s_mean, s_std, r_mean, r_std
OUTPUT_IDX = (0, 1, 2, 3)
OUTPUT_NAMES = ("s_mean_um", "s_std_um", "r_mean", "r_std")


def jacobians(model, x, u, p=None, dt_h: float | None = None):
    """(A, B) of the continuous field (dt_h None, per hour) or of the step map over ``dt_h``."""
    import casadi as ca

    xs, us, ps = ca.SX.sym("x", 6), ca.SX.sym("u", 2), ca.SX.sym("p", 2)
    if dt_h is None:
        f = model.rhs(xs, us, ps, xp=ca)
    else:
        f = model.casadi_step(dt_h)(xs, us, ps)
    J = ca.Function("J", [xs, us, ps], [ca.jacobian(f, xs), ca.jacobian(f, us)])
    pp = model.p0() if p is None else np.asarray(p, dtype=float)
    A, Bm = J(np.asarray(x, dtype=float), np.asarray(u, dtype=float), pp)
    return np.array(A), np.array(Bm)


def linearize(model, x, u, p=None, dt_h: float | None = None):
    """python-control ``StateSpace`` of the moment model at (x, u, p).

    Continuous (time in hours) when ``dt_h`` is None, else discrete with period ``dt_h``.
    Outputs are the four micrograph moments; inputs (rpm, milling).
    """
    import control

    A, Bm = jacobians(model, x, u, p, dt_h)
    C = np.zeros((len(OUTPUT_IDX), 6))
    for i, k in enumerate(OUTPUT_IDX):
        C[i, k] = 1.0
    D = np.zeros((len(OUTPUT_IDX), 2))
    kw = dict(inputs=list(model.input_names), outputs=list(OUTPUT_NAMES), states=list(model.state_names))
    if dt_h is None:
        return control.ss(A, Bm, C, D, **kw)
    return control.ss(A, Bm, C, D, dt_h, **kw)
