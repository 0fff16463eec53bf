"""Named card parameters: read and set any numeric card field by name.

The paper's four factors have short names (``alpha``, ``beta``, ``gamma``, ``delta``:
``stochastic.alpha``, ``stochastic.beta``, ``stochastic.gamma_per_um2``,
``stochastic.delta_per_um2``, eqns 9, 15, 20); any other numeric field is named
``section.field`` (``partition.strain_efficiency``, ``thermal.softening_max``, ...).
Setting goes through the card's validation, so a value the card forbids is an InputError.
"""

from __future__ import annotations

from typing import Mapping, Sequence

from ..config import ModelCard, validate
from ..errors import InputError

ALIASES = {
    "alpha": "stochastic.alpha",
    "beta": "stochastic.beta",
    "gamma": "stochastic.gamma_per_um2",
    "delta": "stochastic.delta_per_um2",
}
DEFAULT_PARAMS = ("alpha", "beta", "gamma", "delta")


def field_of(name: str) -> tuple[str, str]:
    """(section, field) of a parameter name (an alias or ``section.field``)."""
    full = ALIASES.get(name, name)
    if full.count(".") != 1:
        raise InputError(f"--params: unknown parameter {name!r} (use alpha, beta, gamma, delta or section.field)")
    sec, fld = full.split(".")
    return sec, fld


def parse_params(text: str, card: ModelCard) -> list[str]:
    """Names from a comma-separated ``--params`` value, each a numeric field of ``card``."""
    names = [t.strip() for t in text.split(",") if t.strip()]
    if not names:
        raise InputError("--params: no parameter named")
    if len(set(names)) != len(names):
        raise InputError(f"--params: a parameter is named twice ({text})")
    for n in names:
        get_param(card, n)
    return names


def get_param(card: ModelCard, name: str) -> float:
    """The value of a named numeric card parameter."""
    sec, fld = field_of(name)
    part = getattr(card, sec, None)
    if part is None or fld not in type(part).model_fields:
        raise InputError(f"--params: {name!r}: the card has no field {sec}.{fld}")
    v = getattr(part, fld)
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise InputError(f"--params: {name!r}: {sec}.{fld} is not a number")
    return float(v)


def get_params(card: ModelCard, names: Sequence[str]) -> list[float]:
    """Values of several named parameters."""
    return [get_param(card, n) for n in names]


def set_params(card: ModelCard, values: Mapping[str, float], source: str = "calibrated card") -> ModelCard:
    """A validated copy of ``card`` with the named parameters set.

    Parameters
    ----------
    card : ModelCard
    values : mapping
        Parameter name (alias or ``section.field``) -> new value.
    source : str, optional
        Named in the error message if the card rejects a value.

    Returns
    -------
    ModelCard

    Examples
    --------
    >>> from bmctl.plant.plant import default_card
    >>> c = set_params(default_card(), {"gamma": 2e-4, "partition.max_strain": 0.4})
    >>> c.stochastic.gamma_per_um2, c.partition.max_strain
    (0.0002, 0.4)
    """
    d = card.model_dump()
    for name, v in values.items():
        sec, fld = field_of(name)
        get_param(card, name)
        old = d[sec][fld]
        d[sec][fld] = int(round(v)) if isinstance(old, int) and not isinstance(old, bool) else float(v)
    return validate(type(card), d, source)
