"""Campaign targets: what the user asks for, mapped onto what the controller tracks.

The controller tracks the four micrograph moments and the volume-weighted D-values
(:data:`bmctl.control.config.TARGET_KEYS`): those keys pass through unchanged. Other keys can
be registered in :data:`TARGETS` with a function that maps their value onto controller
targets, given the current estimate, so the key set grows by adding an entry.

``d50_um`` -- the volume-weighted median size (laser-diffraction D50) -- has one definition
everywhere: the closed form of the size law of a state's number-weighted mean and std
(:func:`bmctl.stats.law_size_stats` of the projected moments,
:func:`bmctl.moments.model.size_stats_of_state`). The particle filter reports it per particle
(mean and 90 % interval over the filter's particles), the controller's D50 target uses the
same closed form, and ``status``, ``advise``, ``status --json`` and the report print the
estimate's ``d50_um`` and its interval as they are.
"""

from __future__ import annotations

import math
from typing import Callable

from ..config import did_you_mean
from ..control.config import NOT_NUMBERS, TARGET_KEYS, check_dvalue_order, target_value
from ..errors import InputError, finite_float, quote

#: extra target keys: name -> (maps value and estimate dict to controller targets, one-line meaning)
TARGETS: dict[str, tuple[Callable[[float, dict], dict[str, float]], str]] = {}


def known_keys() -> tuple[str, ...]:
    """Every key a campaign target may name."""
    return tuple(dict.fromkeys(tuple(TARGET_KEYS) + tuple(TARGETS)))


def parse(text: str, where: str = "--target") -> dict[str, float]:
    """``"d50_um=45,r_mean=0.05"`` -> dict; unknown keys and non-positive values are InputErrors."""
    out: dict[str, float] = {}
    items = [t.strip() for t in str(text).split(",") if t.strip()]
    if not items:
        raise InputError(f"{where}: empty target (expected e.g. d50_um=45 or s_mean_um=40)")
    for item in items:
        if "=" not in item:
            raise InputError(f"{where}: expected key=value, got {item!r}")
        k, v = (s.strip() for s in item.split("=", 1))
        if k not in known_keys():
            raise InputError(f"{where}: unknown target {k!r}{did_you_mean(k, known_keys())} (one of {', '.join(known_keys())})")
        if k in out:
            raise InputError(f"{where}: {k} given twice")
        if ":" in v:  # design and trial scenarios take windows; a campaign steers to one value
            mid = _mid(v)
            raise InputError(f"{where}: {k}={v}: a campaign takes one value per target, not a window"
                             + (f" (e.g. {k}={mid})" if mid else "") + "; windows are for design and trial scenarios")
        val = finite_float(v, f"{where}: {k}")
        if val <= 0:
            raise InputError(f"{where}: {k}: must be > 0 (got {v})")
        out[k] = target_value(k, val, where) if k in TARGET_KEYS else val
    if "d50_um" in out and "s_mean_um" in out:
        raise InputError(f"{where}: d50_um and s_mean_um both set the size; give one")
    check_dvalue_order(out, where)
    return out


def check(target, where: str = "target") -> dict[str, float]:
    """A campaign target given as a mapping (the Python API's ``init(target={...})``), checked as
    :func:`parse` checks its text: each key known, each value one finite number > 0 in its range,
    D90 above D50. Text and flags are not numbers here (``"55"`` is refused, not read as 55).

    Parameters
    ----------
    target : mapping
        ``{key: value}``, e.g. ``{"d50_um": 45.0}`` (or ``(key, value)`` pairs).
    where : str, optional
        What a message names first: the argument (``target``).

    Returns
    -------
    dict
        ``{key: float}``.

    Raises
    ------
    bmctl.errors.InputError
        One line naming ``where`` and the key.

    Examples
    --------
    >>> check({"d50_um": 45})
    {'d50_um': 45.0}
    >>> check({"d50_um": "45"})  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    bmctl.errors.InputError: target: d50_um: not a number: '45' (give the number 45, ...)
    """
    try:
        items = dict(target)
    except (TypeError, ValueError):
        raise InputError(f"{where}: expected a dict such as {{'d50_um': 45.0}} or text such as 'd50_um=45' "
                         f"(got {type(target).__name__})") from None
    out: dict[str, float] = {}
    for k, v in items.items():
        if k not in known_keys():
            raise InputError(f"{where}: unknown target {quote(k)}{did_you_mean(k, known_keys())} "
                             f"(one of {', '.join(known_keys())})")
        if isinstance(v, NOT_NUMBERS):
            raise InputError(f"{where}: {k}: not a number: {quote(v)}{_text_hint(k, v)}")
        if isinstance(v, (list, tuple)):  # design and trial scenarios take windows; a campaign steers to one value
            raise InputError(f"{where}: {k}: a campaign takes one value per target, not a window ({quote(v)}); "
                             "windows are for design and trial scenarios")
        try:
            val = float(v)
        except (TypeError, ValueError):
            raise InputError(f"{where}: {k}: not a number ({quote(v)})") from None
        if not math.isfinite(val):
            raise InputError(f"{where}: {k}: must be a finite number (got {v})")
        if val <= 0:
            raise InputError(f"{where}: {k}: must be > 0 (got {v})")
        out[k] = target_value(k, val, where) if k in TARGET_KEYS else val
    check_dvalue_order(out, where)
    return out


def _text_hint(key: str, value) -> str:
    """For a number given as text in a target mapping: the mapping's form and the text form, e.g.
    `` (give the number 55, or the whole target as text: "d50_um=55")``; empty for anything else.

    >>> _text_hint("d50_um", " 55 "), _text_hint("d50_um", "abc"), _text_hint("d50_um", True)
    (' (give the number 55, or the whole target as text: "d50_um=55")', '', '')
    """
    if not isinstance(value, str) or "_" in value:
        return ""
    try:
        x = float(value)
    except ValueError:
        return ""
    return f' (give the number {x:g}, or the whole target as text: "{key}={x:g}")' if math.isfinite(x) else ""


def _mid(window: str) -> str:
    """The middle of a window ``"lo:hi"`` as text for a message (empty when it is not two finite numbers).

    >>> _mid("60:70"), _mid("a:b")
    ('65', '')
    """
    try:
        lo, hi = (float(x) for x in window.split(":"))
    except ValueError:
        return ""
    mid = (lo + hi) / 2
    return f"{mid:g}" if math.isfinite(mid) else ""


def controller_target(target: dict[str, float], est: dict) -> dict[str, float]:
    """The controller's moment targets for a campaign target at the estimate ``est``."""
    out: dict[str, float] = {}
    for k, v in target.items():
        if k in TARGET_KEYS:
            out[k] = float(v)
        else:
            out.update(TARGETS[k][0](float(v), est))
    return out


def value_of(key: str, values: dict) -> float:
    """The quantity ``key`` of an estimate dict (``s_mean_um``, ``d50_um``, ...); NaN if absent."""
    return float(values.get(key, math.nan))
