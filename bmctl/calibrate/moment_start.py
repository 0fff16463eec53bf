"""Cheap first stage: the moment model's maximum-likelihood gamma and delta multipliers.

The moment model (:mod:`bmctl.moments`) carries (gamma_mult, delta_mult) as parameters and
a closed-form likelihood of measured particles (lognormal s, beta r). A grid over
ln gamma_mult, ln delta_mult in [-ln 4, ln 4], evaluated as one batch through each
history's schedule, gives the plant fit its starting point in milliseconds instead of
plant runs. Other parameters start at the card's values.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from .history import History
from .simulate import pieces

SPAN = float(np.log(4.0))
MAX_STEP_H = 0.5


def moment_start(card_path: str | Path, histories: Sequence[History], names: Sequence[str],
                 n_grid: int = 17) -> tuple[np.ndarray, dict]:
    """Starting ln(value / card value) for ``names``: gamma and delta from the moment model.

    Parameters
    ----------
    card_path : path-like
        The card (its ``.moments.toml`` coefficients are used when they belong to it, else the built-in defaults).
    histories : sequence of History
    names : sequence of str
        The fitted parameters; entries other than gamma and delta start at 0.
    n_grid : int, optional
        Grid points per axis.

    Returns
    -------
    (u0, info)
        ``u0``: array of len(names); ``info``: gamma_mult, delta_mult and the log-likelihood.
    """
    from ..config import load_card
    from ..moments.forcard import status
    from ..moments.model import make_moment_model

    u0 = np.zeros(len(names))
    if "gamma" not in names and "delta" not in names:
        return u0, {}
    card = load_card(card_path)
    own = status(card, card_path).ok  # never the coefficients of another card: then the built-in defaults
    model = make_moment_model(card_path) if own else make_moment_model(card, coeffs="defaults")
    g = np.linspace(-SPAN, SPAN, n_grid)
    G, D = np.meshgrid(g if "gamma" in names else [0.0], g if "delta" in names else [0.0], indexing="ij")
    P = np.exp(np.stack([G.ravel(), D.ravel()], axis=1))
    ll = np.zeros(P.shape[0])
    for hist in histories:
        x = np.repeat(model.x0()[None, :], P.shape[0], axis=0)
        t = 0.0
        for smp in hist.samples:
            for hours, rpm, milling in pieces(hist.segments, t, smp.t_h):
                k = max(1, int(np.ceil(hours / MAX_STEP_H - 1e-9)))
                for _ in range(k):
                    x = model.step(x, np.array([rpm, milling]), hours / k, P)
            t = smp.t_h
            ll += model.loglik(x, smp.s_um, smp.r)
    ll = np.where(np.isfinite(ll), ll, -np.inf)
    # among equally likely points the one nearest the card: samples that saw no milling (all at 0 h) leave
    # the likelihood flat, and the first maximum was the grid's corner (gamma and delta x1/4)
    top = np.flatnonzero(ll >= ll.max() - 1e-9 * max(1.0, abs(float(ll.max())))) if np.isfinite(ll.max()) else [0]
    best = int(min(top, key=lambda i: float(np.sum(np.log(P[i]) ** 2))))
    gm, dm = P[best]
    if "gamma" in names:
        u0[names.index("gamma")] = np.log(gm)
    if "delta" in names:
        u0[names.index("delta")] = np.log(dm)
    return u0, {"gamma_mult": float(gm), "delta_mult": float(dm), "loglik": float(ll[best]),
                "coefficients": str(model.coeffs_source)}
