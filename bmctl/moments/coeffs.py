"""Free coefficients of the moment model: names, defaults, bounds, TOML file next to the card.

The file ``<card>.moments.toml`` is written by ``bmctl identify`` next to the card; it holds
``[coefficients]`` (what the model reads), ``[card]`` (the name and the fingerprint of the card
fields they were identified for, :func:`bmctl.cards.fingerprint_values`), ``[window]`` (the speeds
and steady vial temperatures the identification's plant experiments covered),
``[identification]`` (how they were found) and ``[validation]`` (held-out errors), e.g.::

    [coefficients]
    bond_log_scale = 0.12
    ...
    [card]
    name = "alni-1to1-300rpm-lab"
    fingerprint = "sha256:7b54937f034c04f2"
    [card.values]
    "mill.ball_diameter_m" = 0.01
    ...
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from ..config import read_toml
from ..io import toml_string
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
    return read_file(path).coeffs


#: moments with a held-out error in ``[validation]`` (the model's outputs)
OUTPUTS = ("s_mean_um", "s_std_um", "r_mean", "r_std", "temperature_c")


@dataclass
class CoeffFile:
    """A ``*.moments.toml`` file as read by :func:`read_file`.

    Attributes
    ----------
    path : Path
    coeffs : dict
        ``[coefficients]``, checked against :data:`SPEC`.
    card_name : str or None
        ``[card] name``: the card they were identified for.
    values : dict or None
        ``[card.values]``: the fingerprint fields (None in a file that records none).
    heldout_mean, heldout_max : dict
        ``[validation] mean`` / ``max``: held-out NRMSE per output (fractions; empty when absent).
    window : dict
        ``[window]``: ``rpm`` and ``temperature_c`` as (low, high) pairs (empty when absent).
    identification : dict
        ``[identification]`` as written.
    """

    path: Path
    coeffs: dict
    card_name: str | None = None
    values: dict | None = None
    heldout_mean: dict = field(default_factory=dict)
    heldout_max: dict = field(default_factory=dict)
    window: dict = field(default_factory=dict)
    identification: dict = field(default_factory=dict)
    heldout_schedules: int | None = None

    @property
    def worst_heldout(self) -> tuple[str, float] | None:
        """(output, mean NRMSE) of the worst output over the held-out schedules, or None."""
        items = [(k, v) for k, v in self.heldout_mean.items() if k in OUTPUTS]
        return max(items, key=lambda kv: kv[1]) if items else None

    def heldout_line(self) -> str:
        """Held-out NRMSE per output in one line, e.g. ``held-out NRMSE s_mean 2.2 %, ... (72 schedules)``.

        Examples
        --------
        >>> CoeffFile(Path("x.moments.toml"), {}, heldout_mean={"s_mean_um": 0.022, "r_mean": 0.048}).heldout_line()
        'held-out NRMSE s_mean 2.2 %, r_mean 4.8 %'
        >>> CoeffFile(Path("x.moments.toml"), {}).heldout_line()
        'no held-out error recorded'
        """
        if not self.heldout_mean:
            return "no held-out error recorded"
        parts = [f"{k.removesuffix('_um')} {100 * float(v):.1f} %" for k, v in self.heldout_mean.items()
                 if k in OUTPUTS and k != "temperature_c"]
        n = self.heldout_schedules
        return "held-out NRMSE " + ", ".join(parts) + (f" ({n} schedules)" if n else "")


def _pair(v, where: str) -> tuple[float, float]:
    if (not isinstance(v, list) or len(v) != 2
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)
            or v[0] > v[1]):
        raise InputError(f"{where}: expected [low, high], two finite numbers in order (got {v!r})")
    return float(v[0]), float(v[1])


def _numbers(table, where: str) -> dict:
    if not isinstance(table, dict):
        raise InputError(f"{where}: expected a table")
    out = {}
    for k, v in table.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise InputError(f"{where}.{k}: must be a finite number (got {v!r})")
        out[str(k)] = v
    return out


def read_file(path: str | Path) -> CoeffFile:
    """Read and check a ``*.moments.toml`` file (one-line :class:`~bmctl.errors.InputError` on bad content).

    Parameters
    ----------
    path : path-like
        The coefficient file.

    Returns
    -------
    CoeffFile

    Examples
    --------
    >>> f = read_file("models/alni-1to1-300rpm-lab.moments.toml")
    >>> f.card_name, len(f.values) > 30, sorted(f.window)
    ('alni-1to1-300rpm-lab', True, ['rpm', 'temperature_c'])
    """
    path = Path(path)
    data = read_toml(path)
    table = data.get("coefficients")
    if not isinstance(table, dict):
        raise InputError(f"{path}: coefficients: required table is missing")
    out = CoeffFile(path, check(table, str(path)))
    card = data.get("card")
    if card is not None:
        if not isinstance(card, dict):
            raise InputError(f"{path}: card: expected a table")
        name = card.get("name")
        if name is not None and not isinstance(name, str):
            raise InputError(f"{path}: card.name: expected a string (got {name!r})")
        out.card_name = name
        if "values" in card:
            out.values = _numbers(card["values"], f"{path}: card.values")
        fp = card.get("fingerprint")
        if fp is not None:  # the short name of card.values: an edit of one without the other is caught
            from ..cards import fingerprint

            if not isinstance(fp, str):
                raise InputError(f"{path}: card.fingerprint: expected a string such as \"sha256:...\" (got {fp!r})")
            if out.values is None:
                raise InputError(f"{path}: card.fingerprint: given without the card.values it names")
            if fp != fingerprint(out.values):
                raise InputError(f"{path}: card.fingerprint: {fp} is not the fingerprint of its card.values "
                                 f"({fingerprint(out.values)}): the file was edited; re-identify the card")
    val = data.get("validation", {})
    if isinstance(val, dict):
        for key, attr in (("mean", "heldout_mean"), ("max", "heldout_max")):
            if key in val:
                setattr(out, attr, _numbers(val[key], f"{path}: validation.{key}"))
        n = val.get("schedules")
        out.heldout_schedules = n if isinstance(n, int) and not isinstance(n, bool) else None
    win = data.get("window")
    if win is not None:
        if not isinstance(win, dict):
            raise InputError(f"{path}: window: expected a table")
        out.window = {k: _pair(win[k], f"{path}: window.{k}") for k in ("rpm", "temperature_c") if k in win}
    ident = data.get("identification", {})
    out.identification = dict(ident) if isinstance(ident, dict) else {}
    return out


def _fmt(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(float(v)) if isinstance(v, float) else str(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    return toml_string(str(v))


def _key(k: str) -> str:
    """A TOML key: bare when it can be, else quoted."""
    k = str(k)
    if k and all(ch.isalnum() or ch in "_-" for ch in k) and k.isascii():
        return k
    return toml_string(k)


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
