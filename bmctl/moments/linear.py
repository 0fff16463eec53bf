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
    """(A, B) of the continuous field (dt_h None, per hour) or of the step map over ``dt_h``.

    The point is checked as :meth:`MomentModel.step` checks it: one finite state (hardening in
    [0, 1], temperature above absolute zero), one (rpm, milling) within the card's range and one
    finite (gamma_mult, delta_mult) >= 0, else :class:`bmctl.errors.InputError`.
    """
    import casadi as ca

    x, u, pp = model._check_point(x, u, p)
    xs, us, ps = ca.SX.sym("x", 6), ca.SX.sym("u", 2), ca.SX.sym("p", 2)
    if dt_h is None:
        f = model.rhs(xs, us, ps, xp=ca)
    else:
        f = model.casadi_step(dt_h)(xs, us, ps)
    J = ca.Function("J", [xs, us, ps], [ca.jacobian(f, xs), ca.jacobian(f, us)])
    A, Bm = J(x, u, pp)
    return np.array(A), np.array(Bm)


def linearize(model, x, u, p=None, dt_h: float | None = None):
    """python-control ``StateSpace`` of the moment model at (x, u, p).

    Continuous (time in hours) when ``dt_h`` is None, else discrete with period ``dt_h``.
    Outputs are the four micrograph moments; inputs (rpm, milling). A point :func:`jacobians`
    refuses (wrong shape, not finite, out of range) raises :class:`bmctl.errors.InputError`.
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


def operating_point(model, rpm: float, at_hours: float, dt_h: float = 0.5):
    """State after ``at_hours`` of milling at ``rpm`` from the card's initial state, and u = (rpm, 1)."""
    x = model.x0()
    n = int(round(at_hours / dt_h))
    if n > 0:
        x = model.simulate(x, [[rpm, 1.0]] * n, dt_h)[-1]
    rest = at_hours - n * dt_h
    if rest > 1e-9:
        x = model.step(x, [rpm, 1.0], rest)
    return x, np.array([float(rpm), 1.0])


def scalings(model, x):
    """Typical magnitudes of states and inputs (for ranks and gramians in comparable units)."""
    c = model.const
    dx = np.array([max(abs(x[0]), 1.0), max(abs(x[1]), 1.0), 0.1, 0.1,
                   max(c.power_max_W * c.cooling_time_h * 3600 / c.heat_capacity_J_per_K, 1.0), 0.5])
    du = np.array([model.rpm_max, 1.0])
    return dx, du


def finite_gramian(A, B, horizon_h: float, n: int = 400):
    """Finite-horizon gramian int_0^T e^{At} B B^T e^{A^T t} dt (trapezoid on a fine exact grid)."""
    from scipy.linalg import expm

    dt = horizon_h / n
    E = expm(A * dt)
    P = B.copy()
    W = np.zeros((A.shape[0], A.shape[0]))
    for k in range(n + 1):
        wk = 0.5 if k in (0, n) else 1.0
        W += wk * dt * P @ P.T
        P = E @ P
    return W


def analyse(model, x, u, p=None, horizon_h: float = 2.0) -> dict:
    """Ranks and conditioning of the scaled linearisation at (x, u).

    Returns eigenvalues (1/h), controllability rank from (rpm, milling) and from each input
    alone, observability rank from the four micrograph moments, and the condition numbers
    (sigma_max / sigma_min) of the finite-horizon gramians over ``horizon_h`` hours.
    """
    import control

    sys_ = linearize(model, x, u, p)
    dx, du = scalings(model, x)
    A = np.diag(1 / dx) @ sys_.A @ np.diag(dx)
    Bm = np.diag(1 / dx) @ sys_.B @ np.diag(du)
    C = np.diag(1 / dx[list(OUTPUT_IDX)]) @ sys_.C @ np.diag(dx)

    def rank(M):
        s = np.linalg.svd(M, compute_uv=False)
        return int(np.sum(s > 1e-9 * s[0])) if s[0] > 0 else 0

    Wc = finite_gramian(A, Bm, horizon_h)
    Wo = finite_gramian(A.T, C.T, horizon_h)
    sc = np.linalg.svd(Wc, compute_uv=False)
    so = np.linalg.svd(Wo, compute_uv=False)
    return {
        "x": np.asarray(x, dtype=float), "u": np.asarray(u, dtype=float), "sys": sys_,
        "eig": np.linalg.eigvals(sys_.A),
        "ctrb_rank": rank(control.ctrb(A, Bm)),
        "ctrb_rank_rpm": rank(control.ctrb(A, Bm[:, :1])),
        "ctrb_rank_milling": rank(control.ctrb(A, Bm[:, 1:])),
        "obsv_rank": rank(control.obsv(A, C)),
        "obsv_rank_no_r": rank(control.obsv(A, C[:2])),
        "gram_c_cond": float(sc[0] / max(sc[-1], 1e-300)),
        "gram_o_cond": float(so[0] / max(so[-1], 1e-300)),
        "gram_c_sv": sc, "gram_o_sv": so, "horizon_h": horizon_h,
    }


def step_figure(model, x, u, p=None, hours: float = 4.0, frac: float = 0.1):
    """Figure: linear (continuous) and nonlinear responses of the 4 moments to input steps.

    Steps: +``frac`` rpm_max on rpm (-``frac`` rpm_max where + would pass rpm_max), and -``frac`` on
    milling (from the operating point). Responses are deviations from the unforced nonlinear trajectory.
    """
    import control
    from ..io import pyplot

    plt = pyplot()

    from ..plots import quantity_label

    sys_ = linearize(model, x, u, p)
    t = np.linspace(0.0, hours, 161)
    d_rpm = frac * model.rpm_max if u[0] + frac * model.rpm_max <= model.rpm_max else -frac * model.rpm_max
    steps = [(0, d_rpm, f"rpm {d_rpm:+g}"), (1, -frac, f"milling -{frac:g}")]
    dt = t[1] - t[0]
    base = model.simulate(x, np.tile(u, (t.size - 1, 1)), dt, p)
    fig, axes = plt.subplots(len(OUTPUT_IDX), 2, figsize=(9, 8), sharex=True)
    for col, (k, size, label) in enumerate(steps):
        resp = control.forced_response(sys_, T=t, U=np.outer([1.0 if i == k else 0.0 for i in range(2)], np.full(t.size, size)))
        u2 = np.array(u, dtype=float).copy()
        u2[k] += size
        u2[1] = min(max(u2[1], 0.0), 1.0)
        nl = model.simulate(x, np.tile(u2, (t.size - 1, 1)), dt, p) - base
        for row, (i, name) in enumerate(zip(OUTPUT_IDX, OUTPUT_NAMES)):
            ax = axes[row, col]
            ax.plot(t, resp.outputs[row], label="linear")
            ax.plot(t, nl[:, i], "--", label="nonlinear")
            ax.set_ylabel(f"Δ {quantity_label(name)}", fontsize=7)
            if row == 0:
                ax.set_title(f"step {label}")
            if row == len(OUTPUT_IDX) - 1:
                ax.set_xlabel("time (h)")
    axes[0, 0].legend()
    fig.suptitle(f"{model.card.card.name}: moment-model step responses at rpm {u[0]:g}, s_mean {x[0]:.1f} µm")
    fig.tight_layout()
    return fig
