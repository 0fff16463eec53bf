"""Scenarios for the scenario MPC from the particle filter's posterior (docs/control.md).

The filter reports, for every state and parameter, its weighted mean and 5 %/95 % quantiles.
:func:`filter_scenarios` turns them into (x, p) pairs beside the estimate: (gamma, delta) at
the corners (q05, q95) and (q95, q05) -- a powder that bonds more and breaks less than
estimated, and the reverse -- each with the 95 % vial temperature, then (q95, q95) and
(q05, q05). The MPC shares one plan over the estimate and these scenarios: the mean tracking
cost over all of them, and the temperature ceiling on each.
"""

from __future__ import annotations

import numpy as np

_CORNERS = (("q05", "q95"), ("q95", "q05"), ("q95", "q95"), ("q05", "q05"))


def filter_scenarios(est: dict, n_extra: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """``n_extra`` (x, p) scenarios from a filter estimate dict (``Estimate.as_dict()``).

    Parameters
    ----------
    est : dict
        Keys s_mean_um, s_std_um, r_mean, r_std, temperature_c, gamma_mult, delta_mult with
        ``_q05``/``_q95`` variants (absent quantiles fall back to the mean); hardening optional.
    n_extra : int
        Scenarios besides the estimate itself (at most 4).
    """
    def q(name, which):
        return float(est.get(f"{name}_{which}", est.get(name, 1.0)))

    x = np.array([est["s_mean_um"], est["s_std_um"], est["r_mean"], est["r_std"], q("temperature_c", "q95"),
                  est.get("hardening", 0.0)], dtype=float)
    out = []
    for g, d in _CORNERS[:n_extra]:
        p = np.array([max(q("gamma_mult", g), 1e-3), max(q("delta_mult", d), 1e-3)])
        out.append((x.copy(), p))
    return out


def selection_indices(weights: np.ndarray, n: int) -> np.ndarray:
    """Deterministic systematic selection of ``n`` particle indices by weight (no random draw).

    Parameters
    ----------
    weights : ndarray
        Particle weights (any scale).
    n : int
    """
    w = np.asarray(weights, dtype=float)
    c = np.cumsum(w / w.sum())
    return np.minimum(np.searchsorted(c, (np.arange(n) + 0.5) / n), w.size - 1)


def particle_scenarios(estimator, n: int) -> list[tuple[np.ndarray, np.ndarray]] | None:
    """``n`` (x, p) pairs of a particle filter: a weighted systematic selection of its particles
    (the same selection as ``campaign advise``'s end band); None for an estimator without particles.

    Parameters
    ----------
    estimator : ParticleFilter
    n : int
    """
    X, P = getattr(estimator, "X", None), getattr(estimator, "P", None)
    if X is None or P is None or n <= 0:
        return None
    idx = selection_indices(estimator.weights, n)
    return [(np.asarray(X[i], dtype=float), np.asarray(P[i], dtype=float)) for i in idx]
