"""Typed, validated configuration: model cards, schedules (and helpers for later schemas).

Every loader turns problems into :class:`bmctl.errors.InputError` with a one-line
message that names the file and the field, e.g.::

    models/x.toml: material.yield_stress_Pa: must be > 0 (got -1.0)

Model cards hold SI values; keys carry their unit as a suffix (``_m``, ``_Pa``,
``_kg``, ``_um`` at the user-facing edges, ``_per_um2`` for the paper's
printed factors).
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal, TypeVar

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError

from .errors import InputError

T = TypeVar("T", bound=BaseModel)


def _finite(v: float) -> float:
    if not math.isfinite(v):
        raise ValueError(f"must be a finite number (got {v})")
    return v


Finite = Annotated[float, AfterValidator(_finite)]
Pos = Annotated[float, Field(gt=0), AfterValidator(_finite)]
NonNeg = Annotated[float, Field(ge=0), AfterValidator(_finite)]
Frac = Annotated[float, Field(ge=0, le=1), AfterValidator(_finite)]


class Strict(BaseModel):
    """Base: unknown keys are errors, values are validated on assignment."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True, frozen=False)


class CardInfo(Strict):
    name: str
    description: str = ""
    sources: list[str] = []
    units: str = "SI; a key's suffix names its unit"


class Process(Strict):
    """The paper's operating recipe for this case (used by `bmctl simulate` by default)."""

    rpm: NonNeg
    hours: Pos = 12.0
    mode: Literal["continuous", "interrupted"] = "continuous"
    mill_min: Pos | None = None  # interrupted: minutes milling per cycle
    rest_min: Pos | None = None  # interrupted: minutes resting per cycle


class Mill(Strict):
    """Planetary-mill geometry (Burgio et al. 1991 kinematics)."""

    sun_radius_m: Pos = 0.07
    vial_radius_m: Pos = 0.0225
    vial_height_m: Pos = 0.05
    speed_ratio: Finite = -2.0  # vial spin / sun-disc spin (negative: counter-rotating)
    ball_diameter_m: Pos = 0.010
    ball_count: Annotated[int, Field(ge=1)] = 10
    ball_to_powder_ratio: Pos = 10.0
    ball_modulus_Pa: Pos = 200e9
    ball_density_kg_m3: Pos = 7900.0
    rpm_max: Pos = 600.0


class Material(Strict):
    """Powder and impactor properties (paper Sec. 4.1, molar law of mixtures)."""

    impactor_mass_kg: Pos = 4.14e-3
    elastic_modulus_Pa: Pos = 120e9
    yield_stress_Pa: Pos = 78.7e6
    bond_threshold_J_per_m: Pos = 6.4  # paper: u = 6.4e-6 J/um
    powder_density_kg_m3: Pos = 5200.0


class Stochastic(Strict):
    """The paper's four calibrated factors (eqns 9, 15, 20)."""

    alpha: Pos
    beta: Pos
    gamma_per_um2: Pos  # printed as um^2; dimensionless p_b needs um^-2 (docs/model.md, eqn 15)
    delta_per_um2: Pos


class Partition(Strict):
    """Energy-partition decisions (docs/model.md, eqns 6, 11, 16, 17)."""

    coated_fraction: Frac = 0.2  # share of the powder coating ball/vial surfaces (Maurice & Courtney)
    strain_efficiency: NonNeg = 0.01  # share of plastic heat (8) that does shape-changing work in (11)
    equiaxing_efficiency: NonNeg = 0.0  # share of plastic heat that rounds irregular particles (after 13)
    equiaxing_hardening: NonNeg = 0.0  # a: rounding efficiency scales as max(0, 1 - a h) with hardening h (after 13)
    threshold_sharpness: Pos = 8.0  # k*u in the logistic (17)
    max_strain: Pos = 0.5  # |eps| cap per impact in (11)


class Thermal(Strict):
    """Vial temperature, softening and work hardening (beyond the paper; neutral = all zero)."""

    ambient_C: Finite = 25.0
    heat_capacity_J_per_K: Pos = 800.0
    cooling_time_s: Pos = 1800.0
    softening_max: Annotated[float, Field(ge=0, lt=1)] = 0.0  # S: largest relative loss of yield stress
    softening_scale_K: Pos = 30.0  # T_s: temperature rise for 63 % of S
    hardening_max: NonNeg = 0.0
    hardening_work_J_per_kg: Pos = 1e8
    recovery_time_s: Pos = 1e9  # static recovery of hardening (large = none)
    bond_hardening_exponent: NonNeg = 1.0
    fracture_hardening_exponent: NonNeg = 1.0


class Initial(Strict):
    """Initial powder: Gaussian size, nearly round."""

    s_mean_um: Pos = 40.0
    s_std_um: NonNeg = 4.0
    r_mean: Annotated[float, Field(ge=0, lt=1)] = 0.02


class Simulation(Strict):
    particles: Annotated[int, Field(ge=100, le=10_000_000)] = 20_000
    record_every_h: Pos = 1.0
    batch_fraction: Annotated[float, Field(gt=0, le=0.5)] = 0.05
    max_step_s: Pos = 60.0
    s_max_um: Pos = 1000.0


class ModelCard(Strict):
    """A calibrated parameter set for one milling case (TOML under ``models/``)."""

    card: CardInfo
    process: Process
    mill: Mill = Mill()
    material: Material = Material()
    stochastic: Stochastic
    partition: Partition = Partition()
    thermal: Thermal = Thermal()
    initial: Initial = Initial()
    simulation: Simulation = Simulation()


class Segment(Strict):
    hours: Pos
    rpm: NonNeg


class Schedule(Strict):
    """A list of (hours, rpm) segments; rpm 0 is a rest."""

    name: str = ""
    segment: list[Segment] = Field(min_length=1)


def _fmt_loc(loc: tuple) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out or "(top level)"


def format_validation_error(source: str, err: ValidationError) -> str:
    """One line: ``source: field: message (got value)`` for the first error."""
    e = err.errors()[0]
    loc = _fmt_loc(tuple(p for p in e["loc"] if not (isinstance(p, str) and p.startswith("function-"))))
    msg = e["msg"]
    if msg.startswith("Value error, "):
        msg = msg[len("Value error, "):]
    if e["type"] == "extra_forbidden":
        msg = "unknown field"
    elif e["type"] == "missing":
        msg = "required field is missing"
    elif "input" in e and not isinstance(e["input"], (dict, list)) and "got" not in msg:
        msg += f" (got {e['input']!r})"
    more = len(err.errors()) - 1
    tail = f" (+{more} more problem{'s' if more > 1 else ''})" if more else ""
    return f"{source}: {loc}: {msg}{tail}"


def read_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file; missing/unreadable/malformed files raise InputError."""
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: file not found")
    if p.is_dir():
        raise InputError(f"{p}: is a directory, expected a TOML file")
    try:
        with open(p, "rb") as fh:
            return tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{p}: malformed TOML: {exc}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{p}: cannot read: {exc}") from None


def validate(model: type[T], data: dict[str, Any], source: str) -> T:
    """Validate ``data`` against ``model``; errors become one-line InputError."""
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise InputError(format_validation_error(source, exc)) from None


def load(model: type[T], path: str | Path) -> T:
    """Read and validate a TOML file against ``model``."""
    return validate(model, read_toml(path), str(path))


def load_card(path: str | Path) -> ModelCard:
    """Load a model card (``models/*.toml``).

    Parameters
    ----------
    path : path-like
        The TOML file.

    Returns
    -------
    ModelCard

    Examples
    --------
    >>> from bmctl.config import load_card
    >>> card = load_card("models/alni-1to1-300rpm-lab.toml")  # doctest: +SKIP
    >>> card.stochastic.alpha  # doctest: +SKIP
    2.1
    """
    card = load(ModelCard, path)
    p = card.process
    if p.mode == "interrupted" and (p.mill_min is None or p.rest_min is None):
        raise InputError(f"{path}: process: interrupted mode needs mill_min and rest_min")
    return card


def load_schedule(path: str | Path) -> Schedule:
    """Load a schedule TOML (``[[segment]]`` tables with ``hours`` and ``rpm``)."""
    return load(Schedule, path)


def card_schedule(card: ModelCard, hours: float | None = None, rpm: float | None = None) -> list[tuple[float, float]]:
    """The card's recipe as (hours, rpm) segments, optionally overriding hours and rpm."""
    p = card.process
    total = p.hours if hours is None else hours
    speed = p.rpm if rpm is None else rpm
    if p.mode == "continuous" or rpm is not None and rpm == 0:
        return [(total, speed)]
    mill_h, rest_h = p.mill_min / 60.0, p.rest_min / 60.0
    segs: list[tuple[float, float]] = []
    t = 0.0
    while t < total - 1e-12:
        m = min(mill_h, total - t)
        segs.append((m, speed))
        t += m
        if t < total - 1e-12:
            r = min(rest_h, total - t)
            segs.append((r, 0.0))
            t += r
    return segs


def with_factors(card: ModelCard, gamma_mult: float, delta_mult: float) -> ModelCard:
    """A copy of ``card`` with its contact factor gamma and parting factor delta multiplied
    (eqns 15, 20): a plant whose bonding/fracture propensities are off the card."""
    d = card.model_dump()
    d["stochastic"]["gamma_per_um2"] *= gamma_mult
    d["stochastic"]["delta_per_um2"] *= delta_mult
    return type(card).model_validate(d)
