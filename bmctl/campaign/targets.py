"""Campaign targets: what the user asks for, mapped onto what the controller tracks.

The controller tracks the four micrograph moments (:data:`bmctl.control.config.TARGET_KEYS`):
those keys pass through unchanged. Other keys are registered in :data:`TARGETS` with a
function that maps their value onto controller moments, given the current estimate, so the
key set grows by adding an entry.

``d50_um`` -- the volume-weighted median size (laser-diffraction D50). With a log-normal
size law fitted to the number-weighted mean m and std sd (Hatch-Choate), sigma^2 =
ln(1 + (sd/m)^2) and the volume-weighted median is ``m * (1 + (sd/m)^2)^2.5``. The controller
does not carry a D50 target yet, so ``d50_um`` is tracked as the number-weighted mean
``s_mean_um = d50_um / (1 + cv^2)^2.5`` at the currently estimated spread cv = s_std / s_mean
(re-evaluated at every ``advise``). The report and ``advise`` show the D50 implied by the
estimate next to it.
"""

from __future__ import annotations

import math
from typing import Callable

from ..control.config import TARGET_KEYS
from ..errors import InputError, finite_float


def d50_from_moments(s_mean_um: float, s_std_um: float) -> float:
    """Volume-weighted median size (um) of a log-normal law with number mean and std (um)."""
    cv2 = (s_std_um / s_mean_um) ** 2
    return s_mean_um * (1.0 + cv2) ** 2.5


def _d50_target(value: float, est: dict) -> dict[str, float]:
    cv2 = (est["s_std_um"] / est["s_mean_um"]) ** 2
    return {"s_mean_um": value / (1.0 + cv2) ** 2.5}


#: extra target keys: name -> (maps value and estimate dict to controller targets, one-line meaning)
TARGETS: dict[str, tuple[Callable[[float, dict], dict[str, float]], str]] = {
    "d50_um": (_d50_target, "volume-weighted median size (um), tracked as s_mean_um at the estimated spread"),
}


def known_keys() -> tuple[str, ...]:
    """Every key a campaign target may name."""
    return tuple(dict.fromkeys(tuple(TARGET_KEYS) + tuple(TARGETS)))  # d50_um is in both: named once


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
            raise InputError(f"{where}: unknown target {k!r} (one of {', '.join(known_keys())})")
        if k in out:
            raise InputError(f"{where}: {k} given twice")
        val = finite_float(v, f"{where}: {k}")
        if val <= 0:
            raise InputError(f"{where}: {k}: must be > 0 (got {v})")
        out[k] = val
    if "d50_um" in out and "s_mean_um" in out:
        raise InputError(f"{where}: d50_um and s_mean_um both set the size; give one")
    return out


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
    """The quantity ``key`` of a moment dict (``s_mean_um``, ``s_std_um``, ...); NaN if absent."""
    if key in TARGET_KEYS:
        return float(values.get(key, math.nan))
    if key == "d50_um":
        return d50_from_moments(values["s_mean_um"], values["s_std_um"])
    return math.nan
