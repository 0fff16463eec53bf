"""What a target can name, as functions of the moment-model state: the four particle moments and
the volume-weighted D-values of the size law fitted from (s_mean, s_std).

The D-values come from the closed-form Weibull law of :func:`bmctl.stats.weibull_size_stats`
(numpy or casadi), the law the moment model and the particle filter report (docs/fidelity.md),
so an MPC or a design can put ``d50_um``, ``d90_um`` or ``span`` into its cost.
"""

from __future__ import annotations

import numpy as np

from .config import DVALUE_KEYS, MOMENT_KEYS, TARGET_KEYS

#: floors of the relative-error scales (|ref| below them is treated as the floor)
ERR_FLOOR = {"s_mean_um": 1.0, "s_std_um": 1.0, "r_mean": 0.005, "r_std": 0.005, "d50_um": 1.0, "d90_um": 1.0,
             "span": 0.05}


def output_values(x, keys=TARGET_KEYS):
    """Target quantities of one state or a (6, n) casadi matrix / (n, 6) numpy array of states.

    Parameters
    ----------
    x : ndarray (6,) or (n, 6), or casadi (6, n)
        Moment-model states (s_mean_um, s_std_um, r_mean, r_std, T, h).
    keys : sequence of str
        From :data:`TARGET_KEYS`.

    Returns
    -------
    list
        One entry per key: float / ndarray (numpy) or a (1, n) casadi row.
    """
    is_np = isinstance(x, np.ndarray) or isinstance(x, (list, tuple))
    if is_np:
        xa = np.asarray(x, dtype=float)
        row = (lambda i: xa[..., i])
    else:
        row = (lambda i: x[i, :])
    out = []
    dv = None
    for k in keys:
        if k in MOMENT_KEYS:
            out.append(row(MOMENT_KEYS.index(k)))
        elif k in DVALUE_KEYS:
            if dv is None:
                from ..stats import weibull_size_stats

                dv = weibull_size_stats(row(0), row(1))
            out.append(dv[k])
        else:
            raise KeyError(k)
    return out


def output_dict(x) -> dict[str, float]:
    """All :data:`TARGET_KEYS` of one state, as floats."""
    return {k: float(v) for k, v in zip(TARGET_KEYS, output_values(np.asarray(x, dtype=float)))}


def relative_error(value: float, target) -> float:
    """Relative distance of ``value`` from a point target or outside a window [lo, hi] (0 inside)."""
    from .config import target_bounds

    lo, hi = target_bounds(target)
    scale = max(abs(0.5 * (lo + hi)), 1e-12)
    if value > hi:
        return (value - hi) / scale
    if value < lo:
        return (lo - value) / scale
    return 0.0
