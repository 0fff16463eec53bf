"""Named card parameters: read and set any numeric card field by name; which ones a calibration fits.

The paper's four factors have short names (``alpha``, ``beta``, ``gamma``, ``delta``:
``stochastic.alpha``, ``stochastic.beta``, ``stochastic.gamma_per_um2``,
``stochastic.delta_per_um2``, eqns 9, 15, 20); any other numeric field is named
``section.field`` (``partition.strain_efficiency``, ``thermal.softening_max``, ...).
Setting goes through the card's validation, so a value the card forbids is an InputError.

``bmctl calibrate --params`` fits only the card's model constants (:func:`check_calibratable`):
the constants docs/own-mill.md lists as calibrated on the paper's cases -- ``[stochastic]``,
``material.bond_threshold_J_per_m``, ``[partition]`` and ``[thermal]`` but the room's
``ambient_C``. The mill, the recipe, the powder, the numerical settings and integer counts are
what the user states, not what the data fit.
"""

from __future__ import annotations

from typing import Mapping, Sequence

from ..config import ModelCard, close_key, validate
from ..errors import InputError, quote
from ..naming import arg

ALIASES = {
    "alpha": "stochastic.alpha",
    "beta": "stochastic.beta",
    "gamma": "stochastic.gamma_per_um2",
    "delta": "stochastic.delta_per_um2",
}
DEFAULT_PARAMS = ("alpha", "beta", "gamma", "delta")
#: card tables whose every (continuous) field is a model constant a calibration may fit
CALIBRATABLE_TABLES = ("stochastic", "partition", "thermal")
#: model constants in other tables, and fields of those tables that are not model constants
CALIBRATABLE_FIELDS = frozenset({"material.bond_threshold_J_per_m"})
NOT_CALIBRATABLE = {"thermal.ambient_C": "the room's temperature, an operating condition"}
#: why the fields of the other tables are not fitted
WHY_NOT = {
    "card": "the card's name and notes",
    "process": "an operating setting of the recipe, not a model parameter",
    "simulation": "a numerical setting of the simulation, not a model parameter",
    "validity": "the card's stated range of validity, not a model parameter",
    "mill": "the mill's geometry or loading: measure it",
    "material": "a property of the powder or the balls (their materials give it): state it",
    "powder": "the powder's composition or loading: state it",
    "initial": "the starting powder: measure it (a sample at t = 0)",
}
#: units of a field, by the suffix of its name (docs: a key's suffix names its unit)
UNIT_SUFFIXES = (("_per_um2", "µm^-2"), ("_J_per_m", "J/m"), ("_J_per_K", "J/K"), ("_J_per_kg", "J/kg"),
                 ("_kg_m3", "kg/m^3"), ("_um", "µm"), ("_Pa", "Pa"), ("_kg", "kg"), ("_m", "m"), ("_s", "s"),
                 ("_K", "K"), ("_C", "°C"))


def allowed_text() -> str:
    """What ``--params`` accepts, in words (one line).

    Examples
    --------
    >>> allowed_text()
    'alpha, beta, gamma, delta, material.bond_threshold_J_per_m, or a partition.* or thermal.* field but thermal.ambient_C'
    """
    rest = " or ".join(f"{t}.*" for t in CALIBRATABLE_TABLES if t != "stochastic")
    but = ", ".join(sorted(NOT_CALIBRATABLE))
    return f"{', '.join(DEFAULT_PARAMS)}, {', '.join(sorted(CALIBRATABLE_FIELDS))}, or a {rest} field but {but}"


def _hint(card: ModelCard, name: str) -> str | None:
    """The known parameter name ``name`` most likely mistypes, or None."""
    tables = {t: set(type(getattr(card, t)).model_fields) for t in type(card).model_fields
              if getattr(card, t) is not None}
    if "." not in name:
        return close_key(name, list(ALIASES) + list(CALIBRATABLE_FIELDS))
    sec, _, fld = name.partition(".")
    if sec not in tables:
        hint = close_key(sec, tables)
        return f"{hint}.{fld}" if hint and fld in tables[hint] else None
    hint = close_key(fld, tables[sec])
    aliases = [a for a, full in ALIASES.items() if full.startswith(sec + ".")]
    return f"{sec}.{hint}" if hint else close_key(fld, aliases)


def _unknown(card: ModelCard, name: str) -> InputError:
    """The error of a name that is no field of the card, with the close one and what is allowed."""
    hint = _hint(card, name)
    return InputError(f"{arg('names')}: {quote(name)}: no such parameter{f' (did you mean {hint}?)' if hint else ''}; "
                      f"calibratable: {allowed_text()}")


def field_of(name: str) -> tuple[str, str]:
    """(section, field) of a parameter name (an alias or ``section.field``)."""
    full = ALIASES.get(name, name)
    if full.count(".") != 1:
        raise InputError(f"{arg('names')}: unknown parameter {name!r} (use alpha, beta, gamma, delta or section.field)")
    sec, fld = full.split(".")
    return sec, fld


def param_unit(name: str) -> str:
    """The unit of a named parameter from its field's suffix ("" when it has none: a ratio).

    Examples
    --------
    >>> param_unit("gamma"), param_unit("material.bond_threshold_J_per_m"), param_unit("alpha")
    ('µm^-2', 'J/m', '')
    """
    fld = ALIASES.get(name, name).rpartition(".")[2]
    return next((unit for suffix, unit in UNIT_SUFFIXES if fld.endswith(suffix)), "")


def check_calibratable(card: ModelCard, name: str) -> None:
    """Refuse a parameter a calibration must not fit, before any work (one line naming the argument:
    ``names`` from Python, ``--params`` from ``bmctl calibrate``).

    A fitted parameter is a continuous model constant with a positive value on the card (the
    fit moves u = ln(value / card value)): see the module for which ones.

    Parameters
    ----------
    card : ModelCard
        The starting card.
    name : str
        An alias or ``section.field``.

    Raises
    ------
    InputError
        An unknown or non-numeric field, an integer, a field that is not a model constant, or
        one that is 0 on the card.
    """
    full = ALIASES.get(name, name)
    sec, _, fld = full.partition(".")
    part = getattr(card, sec, None) if sec in type(card).model_fields else None
    if part is None or fld not in type(part).model_fields:
        raise _unknown(card, name)
    value = getattr(part, fld)
    if isinstance(value, int) and not isinstance(value, bool):
        raise InputError(f"{arg('names')}: {full} is an integer (a count), not a continuous parameter; "
                         f"calibratable: {allowed_text()}")
    if full in NOT_CALIBRATABLE or (sec not in CALIBRATABLE_TABLES and full not in CALIBRATABLE_FIELDS):
        why = NOT_CALIBRATABLE.get(full) or WHY_NOT.get(sec, "not a model parameter")
        raise InputError(f"{arg('names')}: {full} is {why}; calibratable: {allowed_text()}")
    if isinstance(value, bool) or not isinstance(value, float):
        raise InputError(f"{arg('names')}: {full} is not a number; calibratable: {allowed_text()}")
    if not value > 0:
        raise InputError(f"{arg('names')}: {full} is {value:g} on the card: the fit scales the card's value "
                         f"(u = ln(value / card value)), so it cannot leave {value:g}; state a positive starting value "
                         "in the card")


def parse_params(text: str, card: ModelCard) -> list[str]:
    """Names from a comma-separated ``--params`` value, each a calibratable field of ``card``
    (:func:`check_calibratable`)."""
    names = [t.strip() for t in text.split(",")]
    if not any(names):
        raise InputError(f"{arg('names')}: no parameter named")
    if not all(names):
        raise InputError(f"{arg('names')}: an empty entry in {quote(text)} (expected names separated by commas)")
    if len({ALIASES.get(n, n) for n in names}) != len(names):
        raise InputError(f"{arg('names')}: a parameter is named twice ({text})")
    for n in names:
        check_calibratable(card, n)
    return names


def get_param(card: ModelCard, name: str) -> float:
    """The value of a named numeric card parameter."""
    sec, fld = field_of(name)
    part = getattr(card, sec, None)
    if part is None or fld not in type(part).model_fields:
        raise InputError(f"{arg('names')}: {name!r}: the card has no field {sec}.{fld}")
    v = getattr(part, fld)
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise InputError(f"{arg('names')}: {name!r}: {sec}.{fld} is not a number")
    return float(v)


def param_bounds(card: ModelCard, name: str) -> tuple[float, float]:
    """The closed range the card accepts for a named parameter (its field's bounds; a strict bound
    moved inside by a relative 1e-9), so a fit can keep every trial value valid.

    Examples
    --------
    >>> from bmctl.config import load_card
    >>> lo, hi = param_bounds(load_card("models/alni-1to1-300rpm-lab.toml"), "thermal.softening_max")
    >>> lo, hi < 1.0, round(hi, 6)
    (0.0, True, 1.0)
    >>> param_bounds(load_card("models/alni-1to1-300rpm-lab.toml"), "alpha")
    (0.1, 20.0)
    """
    import math

    sec, fld = field_of(name)
    lo, hi = -math.inf, math.inf
    for m in type(getattr(card, sec)).model_fields[fld].metadata:
        if getattr(m, "ge", None) is not None:
            lo = max(lo, float(m.ge))
        if getattr(m, "gt", None) is not None:
            lo = max(lo, float(m.gt) + 1e-9 * max(abs(float(m.gt)), 1e-300))
        if getattr(m, "le", None) is not None:
            hi = min(hi, float(m.le))
        if getattr(m, "lt", None) is not None:
            hi = min(hi, float(m.lt) - 1e-9 * max(abs(float(m.lt)), 1e-300))
    return lo, hi


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
