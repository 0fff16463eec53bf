"""Free coefficients of the moment model: names, defaults, bounds, TOML file next to the card.

The file ``models/<card-name>.moments.toml`` is written by ``bmctl identify``; it holds
``[coefficients]`` (what the model reads), ``[identification]`` (how they were found)
and ``[validation]`` (held-out errors), e.g.::

    [coefficients]
    bond_log_scale = 0.12
    ...
"""

from __future__ import annotations

import math
from pathlib import Path

from ..config import read_toml
from ..errors import InputError

#: name -> (default, lower, upper, meaning). Slopes/offsets default to the derived laws of
#: physics.derived_threshold_laws (filled in by the model); "None" marks those.
SPEC: dict[str, tuple[float | None, float, float, str]] = {
    "bond_log_scale": (0.0, -4.0, 4.0, "ln multiplier on the bonding rate (eqns 15-17 averaged)"),
    "bond_slope": (None, 0.3, 12.0, "slope of the averaged bonding threshold law in ln intensity"),
    "bond_offset": (None, -8.0, 8.0, "offset of the averaged bonding threshold law"),
    "frac_log_scale": (0.0, -4.0, 4.0, "ln multiplier on the fracture rate (eqns 17, 20 averaged)"),
    "frac_slope": (None, 0.3, 12.0, "slope of the averaged fracture threshold law in ln intensity"),
    "frac_offset": (None, -8.0, 8.0, "offset of the averaged fracture threshold law"),
    "round_log_scale": (0.0, -4.0, 4.0, "ln multiplier on the equiaxing (rounding) rate"),
    "round_size_bias": (0.0, -2.0, 6.0, "size bias of the rounding: lam taken at s exp(k sigma_ln^2)"),
    "round_var_log_scale": (0.0, -3.0, 3.0, "ln multiplier on the rounding of E[r^2] relative to E[r]"),
    "round_rpm_slope": (0.0, -6.0, 6.0, "empirical: ln rounding rate changes by this per unit rpm/rpm_max"),
    "round_var_rpm_slope": (0.0, -6.0, 6.0, "empirical: ln rounding of E[r^2] changes by this per unit rpm/rpm_max"),
    "bond_ds_gain": (1.0, 0.2, 3.0, "multiplier on the change of sum(s) per bond"),
    "frac_ds_gain": (1.0, 0.2, 3.0, "multiplier on the change of sum(s) per fracture"),
    "bond_r_gain": (1.0, 0.2, 3.0, "multiplier on the aspect ratio of a bonded particle (eqn 18)"),
    "frac_r_gain": (1.0, 0.0, 3.0, "multiplier on the aspect ratio of fracture fragments"),
    "r_var_gain": (1.0, 0.2, 5.0, "multiplier on the r-variance source of bonding and fracture"),
    "bond_rpm_slope": (0.0, -6.0, 6.0, "empirical: ln bonding rate changes by this per unit rpm/rpm_max"),
    "frac_rpm_slope": (0.0, -6.0, 6.0, "empirical: ln fracture rate changes by this per unit rpm/rpm_max"),
    "r_size_corr": (0.0, -1.0, 6.0, "s-r closure: slope of logit E[r | s] in ln s (0 = mean field, r independent of s)"),
    "frac_link_shift": (0.0, -6.0, 6.0, "s-r closure: change of the link slope seen by the fracture terms (0 = the same link)"),
    "r_link_cv_slope": (0.0, -3.0, 3.0, "s-r closure: change of the link slope per unit ln CV^2 of r (where r sits on a few irregular particles)"),
    "frac_link_cv_shift": (0.0, -3.0, 3.0, "s-r closure: change of the fracture link's extra slope per unit ln CV^2 of r"),
}

NAMES = tuple(SPEC)


def coeffs_path(card_path: str | Path) -> Path:
    """``models/x.toml`` -> ``models/x.moments.toml``."""
    p = Path(card_path)
    return p.with_name(p.name.removesuffix(".toml") + ".moments.toml")


def defaults(derived: dict[str, float]) -> dict[str, float]:
    """Default coefficients: 0/1 multipliers and the derived threshold laws."""
    out = {}
    for k, (d, _lo, _hi, _m) in SPEC.items():
        out[k] = float(derived[k] if d is None else d)
    return out


def check(coeffs: dict, source: str) -> dict[str, float]:
    """Validate a coefficient table: known names, finite numbers within bounds."""
    out = {}
    for k, v in coeffs.items():
        if k not in SPEC:
            raise InputError(f"{source}: coefficients.{k}: unknown coefficient")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise InputError(f"{source}: coefficients.{k}: must be a finite number (got {v!r})")
        lo, hi = SPEC[k][1], SPEC[k][2]
        if not lo <= v <= hi:
            raise InputError(f"{source}: coefficients.{k}: must be in [{lo:g}, {hi:g}] (got {v:g})")
        out[k] = float(v)
    return out


def load_coeffs(path: str | Path) -> dict[str, float]:
    """Read the ``[coefficients]`` table of a ``*.moments.toml`` file."""
    data = read_toml(path)
    table = data.get("coefficients")
    if not isinstance(table, dict):
        raise InputError(f"{path}: coefficients: required table is missing")
    return check(table, str(path))


def _fmt(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(float(v)) if isinstance(v, float) else str(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    return '"' + str(v).replace("\\", "\\\\").replace('"', '\\"') + '"'


def _key(k: str) -> str:
    """A TOML key: bare when it can be, else quoted."""
    k = str(k)
    if k and all(ch.isalnum() or ch in "_-" for ch in k) and k.isascii():
        return k
    return '"' + k.replace("\\", "\\\\").replace('"', '\\"') + '"'


def toml_text(coeffs: dict[str, float], sections: dict[str, dict] | None = None, header: str = "") -> str:
    """TOML text with ``[coefficients]`` first, then the other (flat or one-level nested) sections."""
    lines = [f"# {ln}" for ln in header.splitlines()] + ([""] if header else [])
    lines.append("[coefficients]")
    for k in NAMES:
        if k in coeffs:
            lines.append(f"{k} = {float(coeffs[k])!r}")
    for name, table in (sections or {}).items():
        lines.append("")
        lines.append(f"[{name}]")
        nested = {}
        for k, v in table.items():
            if isinstance(v, dict):
                nested[k] = v
            else:
                lines.append(f"{_key(k)} = {_fmt(v)}")
        for k, sub in nested.items():
            lines.append("")
            lines.append(f"[{_key(name)}.{_key(k)}]")
            for kk, vv in sub.items():
                lines.append(f"{_key(kk)} = {_fmt(vv)}")
    return "\n".join(lines) + "\n"
