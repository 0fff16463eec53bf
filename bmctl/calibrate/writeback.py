"""The estimator writes back: particle-filter gamma, delta estimates into a calibrated card.

Online learning during one batch (``bmctl estimate``, the filter in trials) becomes the
starting card of the next: the card's gamma and delta (eqns 15, 20) are multiplied by the
filter's posterior means of gamma_mult and delta_mult at the last sample.
"""

from __future__ import annotations

from pathlib import Path

from ..config import ModelCard
from .outputs import calibrated_card, write_card


def card_from_multipliers(card: ModelCard, gamma_mult: float, delta_mult: float, note: str) -> ModelCard:
    """``card`` with gamma and delta multiplied (eqns 15, 20), renamed ``-calibrated``, ``note`` in its sources.

    Parameters
    ----------
    card : ModelCard
    gamma_mult, delta_mult : float
        Estimated multipliers of the card's gamma and delta (> 0).
    note : str
        Where the estimates came from.
    """
    st = card.stochastic
    return calibrated_card(card, ("gamma", "delta"),
                           (st.gamma_per_um2 * gamma_mult, st.delta_per_um2 * delta_mult), note)


def write_estimate_card(path: str | Path, card: ModelCard, estimate: dict, source: str) -> Path:
    """Write the card calibrated by a filter estimate (``Estimate.as_dict()``: gamma_mult, delta_mult, q05, q95).

    Parameters
    ----------
    path : path-like
        Output TOML.
    card : ModelCard
        The card the filter ran on.
    estimate : dict
        The last estimate as a dict.
    source : str
        Describes the data (named in the card's sources).

    Returns
    -------
    Path
    """
    g, d = float(estimate["gamma_mult"]), float(estimate["delta_mult"])
    note = (f"gamma x{g:.3f} [90 %: {estimate['gamma_mult_q05']:.3f}, {estimate['gamma_mult_q95']:.3f}], "
            f"delta x{d:.3f} [90 %: {estimate['delta_mult_q05']:.3f}, {estimate['delta_mult_q95']:.3f}] "
            f"from bmctl estimate on {source}")
    new = card_from_multipliers(card, g, d, note)
    return write_card(path, new, header=f"{new.card.name}: {note}")
