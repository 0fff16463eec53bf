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
import re
from pathlib import Path
from typing import Annotated, Any, Literal, TypeVar

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from .errors import InputError, quote
from .limits import BALL_TO_POWDER_RANGE, HOURS_MAX, HOURS_MIN, PHASE_MAX_MINUTES, PHASE_MIN_MINUTES, RPM_MAX

T = TypeVar("T", bound=BaseModel)

#: a settings file larger than this is not a settings file
TOML_MAX_BYTES = 1 << 20


def _finite(v: float) -> float:
    if not math.isfinite(v):
        raise ValueError(f"must be a finite number (got {v})")
    return v


Finite = Annotated[float, AfterValidator(_finite)]
Pos = Annotated[float, Field(gt=0), AfterValidator(_finite)]
NonNeg = Annotated[float, Field(ge=0), AfterValidator(_finite)]
Frac = Annotated[float, Field(ge=0, le=1), AfterValidator(_finite)]


def Range(lo: float, hi: float, lo_open: bool = False, hi_open: bool = False) -> Any:
    """A finite float in [lo, hi] (``lo_open``/``hi_open``: that end excluded).

    Every physical field of a card has such a range, from physics and from where the
    model holds; the reason is the comment beside the field (docs/own-mill.md lists them).
    """
    bounds = {("gt" if lo_open else "ge"): lo, ("lt" if hi_open else "le"): hi}
    return Annotated[float, Field(**bounds), AfterValidator(_finite)]


#: a sun-disc speed, [0, 2000] rpm (bmctl.limits.RPM_MAX)
RPM = Range(0.0, RPM_MAX)
#: a duration: one second to one batch of 1,000 h (bmctl.limits)
HOURS = Range(HOURS_MIN, HOURS_MAX)
#: a mill or rest phase in minutes: 6 s to a day
MINUTES = Range(PHASE_MIN_MINUTES, PHASE_MAX_MINUTES)


#: the longest text any settings field may hold (names, descriptions, paths)
TEXT_MAX_CHARS = 1000
_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")


def _plain_text(value, depth: int = 0):
    """``value`` unchanged, or ValueError when a text in it (keys too) holds a control character."""
    if isinstance(value, str):
        m = _CONTROL.search(value)
        if m:
            raise ValueError(f"text with a control character ({m.group()!r}) is not allowed: names and "
                             "descriptions are one line")
    elif isinstance(value, (list, tuple)) and depth < 8:
        for x in value:
            _plain_text(x, depth + 1)
    elif isinstance(value, dict) and depth < 8:
        for k, x in value.items():
            _plain_text(k, depth + 1)
            _plain_text(x, depth + 1)
    return value


class Strict(BaseModel):
    """Base: unknown keys are errors, values are validated on assignment, and numbers must be
    numbers (strict mode: no string or boolean coercion; an integer is accepted for a float,
    as TOML writes 300 for 300.0). Text is one line (no control characters) of at most
    :data:`TEXT_MAX_CHARS` characters.

    Built directly (``FilterSettings(n_particle=100)``) a bad setting raises pydantic's
    ``ValidationError``; :func:`validate` (``validate(FilterSettings, {"n_particle": 100},
    "settings")``) raises the one-line :class:`bmctl.errors.InputError` the command line prints,
    naming the field ("settings: n_particle: unknown field (did you mean n_particles?)")."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True, frozen=False, strict=True,
                              str_max_length=TEXT_MAX_CHARS)

    @field_validator("*", mode="after")
    @classmethod
    def _one_line_text(cls, value):
        return _plain_text(value)


class CardInfo(Strict):
    name: str
    description: str = ""
    sources: list[str] = []
    units: str = "SI; a key's suffix names its unit"


class Process(Strict):
    """The paper's operating recipe for this case (used by `bmctl simulate` by default)."""

    rpm: RPM
    hours: HOURS = 12.0
    mode: Literal["continuous", "interrupted"] = "continuous"
    # interrupted cycles: 6 s to a day per phase (shorter phases would not be resolved by the
    # plant's time step and would multiply the schedule's segments)
    mill_min: MINUTES | None = None  # interrupted: minutes milling per cycle
    rest_min: MINUTES | None = None  # interrupted: minutes resting per cycle


class Mill(Strict):
    """Planetary-mill geometry (Burgio et al. 1991 kinematics)."""

    sun_radius_m: Range(0.01, 1.0) = 0.07  # laboratory to pilot planetary mills: 5-50 cm
    vial_radius_m: Range(0.002, 0.5) = 0.0225  # 2 mm (micro vials) to 50 cm
    vial_height_m: Range(0.002, 1.0) = 0.05
    # vial spin / sun-disc spin: counter-rotating (negative) in every planetary mill; Burgio's
    # velocity holds for -4 <= ratio <= -0.25 (commercial mills: -1 to -3)
    speed_ratio: Range(-4.0, -0.25) = -2.0
    ball_material: str | None = None  # a bmctl.materials name: gives density and modulus
    ball_diameter_m: Range(1e-4, 0.05) = 0.010  # 0.1-50 mm grinding balls
    ball_count: Annotated[int, Field(ge=1, le=100_000)] = 10
    ball_to_powder_ratio: Range(*BALL_TO_POWDER_RANGE) = 10.0  # mass ratio; mechanical alloying uses 1:1-100:1
    ball_modulus_Pa: Range(1e9, 1.2e12) = 200e9  # polymers excluded; diamond is 1.2 TPa
    ball_density_kg_m3: Range(1000.0, 20000.0) = 7900.0  # nylon-coated to tungsten
    rpm_max: Range(0.0, RPM_MAX, lo_open=True) = 600.0  # the mill's own limit (kinematics: RPM above)


class Material(Strict):
    """Powder and impactor properties (paper Sec. 4.1, molar law of mixtures)."""

    impactor_mass_kg: Range(1e-9, 1.0) = 4.14e-3  # one ball (checked against diameter and density)
    elastic_modulus_Pa: Range(1e9, 1.2e12) = 120e9
    yield_stress_Pa: Range(1e5, 1e10) = 78.7e6  # soft solders (~1 MPa) to hard steels (~5 GPa)
    # u: outside ~[0.01, 1000] J/m every impact (or none) bonds or breaks at any rpm (paper: 6.4)
    bond_threshold_J_per_m: Range(0.01, 1000.0) = 6.4  # paper: u = 6.4e-6 J/um
    powder_density_kg_m3: Range(500.0, 25000.0) = 5200.0  # lithium to osmium


class Powder(Strict):
    """What the powder is made of: materials of bmctl.materials and their molar ratio."""

    materials: list[str] = Field(min_length=1, max_length=8)
    molar_ratio: list[Range(0.0, 1e6, lo_open=True)] = Field(min_length=1, max_length=8)
    mass_kg: Range(1e-6, 100.0) | None = None  # total powder loading (else from ball_to_powder_ratio)


class Validity(Strict):
    """Where the card holds; runs that leave it warn (rpm, temperature, sizes); the mill's own top speed,
    ``mill.rpm_max``, is what refuses a faster run."""

    rpm_max: Range(0.0, RPM_MAX, lo_open=True) | None = None  # default: mill.rpm_max
    s_min_um: Range(0.01, 1e5) | None = None  # default: 1 um (below, Hertzian trapping is unmodelled)
    s_max_um: Range(0.01, 1e5) | None = None  # default: simulation.s_max_um
    # default: the lowest melting point of the powder's materials (above it nothing here holds)
    temperature_max_C: Range(-200.0, 4000.0) | None = None
    # the hottest steady vial temperature of the data the card's constants were calibrated on: runs whose
    # steady vial temperature goes above it warn (bmctl.cards.window_warnings; docs/moments.md, Sec. 9)
    calibrated_temperature_max_C: Range(-200.0, 4000.0) | None = None


class Stochastic(Strict):
    """The paper's four calibrated factors (eqns 9, 15, 20)."""

    # logistic exponents of eqn (9): the paper fits 1.7-2.2; beyond [0.1, 20] the pdfs degenerate
    alpha: Range(0.1, 20.0)
    beta: Range(0.1, 20.0)
    # printed as um^2; dimensionless p_b needs um^-2 (docs/model.md, eqn 15); paper 1e-4-1e-3,
    # above 1 um^-2 every contact of a 1 um particle would saturate
    gamma_per_um2: Range(0.0, 1.0, lo_open=True)
    delta_per_um2: Range(0.0, 1.0, lo_open=True)


class Partition(Strict):
    """Energy-partition decisions (docs/model.md, eqns 6, 11, 16, 17)."""

    # share of the powder coating ball/vial surfaces (Maurice & Courtney); below 1e-4 no powder is
    # ever trapped in an impact (and the moment model's energy per trapped area divides by it)
    coated_fraction: Range(1e-4, 1.0) = 0.2
    strain_efficiency: Frac = 0.01  # share of plastic heat (8) that does shape-changing work in (11)
    equiaxing_efficiency: Frac = 0.0  # share of plastic heat that rounds irregular particles (after 13)
    # a: rounding efficiency scales as max(0, 1 - a h) with hardening h in [0, 1) (after 13)
    equiaxing_hardening: Range(0.0, 100.0) = 0.0
    threshold_sharpness: Range(0.1, 1000.0) = 8.0  # k*u in the logistic (17)
    max_strain: Range(0.0, 1.0, lo_open=True) = 0.5  # |eps| cap per impact in (11)


class Thermal(Strict):
    """Vial temperature, softening and work hardening (beyond the paper; neutral = all zero)."""

    ambient_C: Range(-200.0, 100.0) = 25.0  # cryo-milling (liquid N2) to a hot room
    # vial and balls: a 10 ml vial with its balls is ~50 J/K, a 500 ml steel vial ~5 kJ/K
    heat_capacity_J_per_K: Range(1.0, 1e6) = 800.0
    cooling_time_s: Range(1.0, 1e7) = 1800.0
    softening_max: Annotated[float, Field(ge=0, lt=1), AfterValidator(_finite)] = 0.0  # S: largest loss
    softening_scale_K: Range(0.1, 2000.0) = 30.0  # T_s: temperature rise for 63 % of S
    hardening_max: Range(0.0, 100.0) = 0.0  # H: sigma rises to (1 + H) sigma when fully hardened
    hardening_work_J_per_kg: Range(1.0, 1e12) = 1e8
    recovery_time_s: Range(1.0, 1e12) = 1e9  # static recovery of hardening (large = none)
    # thresholds scale as ratio^n with ratio in (0, 1 + H]: |n| <= 20 keeps them finite
    bond_hardening_exponent: Range(0.0, 20.0) = 1.0
    fracture_hardening_exponent: Range(0.0, 20.0) = 1.0


class Initial(Strict):
    """Initial powder: Gaussian size, nearly round."""

    s_mean_um: Range(0.1, 1e4) = 40.0
    s_std_um: Range(0.0, 1e4) = 4.0
    r_mean: Annotated[float, Field(ge=0, lt=1), AfterValidator(_finite)] = 0.02


class Simulation(Strict):
    particles: Annotated[int, Field(ge=100, le=10_000_000)] = 20_000
    record_every_h: Range(1e-3, 1000.0) = 1.0  # 3.6 s to the longest batch
    batch_fraction: Range(1e-4, 0.5) = 0.05  # share of the particles per step (smaller: more steps)
    max_step_s: Range(1e-3, 3600.0) = 60.0
    s_max_um: Range(1.0, 1e5) = 1000.0  # raster extent: 1 um bins, memory grows with it
    # how the plant draws U_in (5) and zeta, xi (9): inverse-CDF tables, one uniform per variate,
    # or numpy's Gamma/Beta samplers (same laws, the streams of earlier versions); docs/model.md
    samplers: Literal["tabulated", "exact"] = "tabulated"


class ModelCard(Strict):
    """A calibrated parameter set for one milling case (TOML under ``models/``)."""

    card: CardInfo
    process: Process
    mill: Mill = Mill()
    material: Material = Material()
    powder: Powder | None = None
    validity: Validity = Validity()
    stochastic: Stochastic
    partition: Partition = Partition()
    thermal: Thermal = Thermal()
    initial: Initial = Initial()
    simulation: Simulation = Simulation()

    @model_validator(mode="after")
    def _consistent(self):
        m = self.mill
        if m.ball_diameter_m >= 2 * m.vial_radius_m or m.ball_diameter_m >= m.vial_height_m:
            raise ValueError(f"mill.ball_diameter_m: a {m.ball_diameter_m * 1e3:g} mm ball does not fit a vial of "
                             f"{2 * m.vial_radius_m * 1e3:g} x {m.vial_height_m * 1e3:g} mm")
        balls = m.ball_count * math.pi / 6 * m.ball_diameter_m**3
        vial = math.pi * m.vial_radius_m**2 * m.vial_height_m
        if balls > 0.64 * vial:  # random close packing: no room left to fly
            raise ValueError(f"mill.ball_count: {m.ball_count} balls fill {balls / vial:.0%} of the vial "
                             "(at most 64 %, random close packing)")
        if self.process.rpm > m.rpm_max:
            raise ValueError(f"process.rpm: {self.process.rpm:g} exceeds mill.rpm_max {m.rpm_max:g}")
        if self.initial.s_mean_um >= self.simulation.s_max_um:
            raise ValueError(f"initial.s_mean_um: {self.initial.s_mean_um:g} is not below simulation.s_max_um "
                             f"{self.simulation.s_max_um:g}")
        from .cards import size_range

        v = self.validity
        s_lo, s_hi = size_range(self)
        if s_lo >= s_hi:  # an empty size range: every run would warn from its first record
            where = "validity.s_min_um" if v.s_min_um is not None else "validity.s_max_um"
            raise ValueError(f"{where}: sizes {s_lo:g} to {s_hi:g} µm are an empty range (s_min_um must be below "
                             f"s_max_um{'' if v.s_max_um is not None else ', default simulation.s_max_um'})")
        amb = self.thermal.ambient_C
        for key in ("temperature_max_C", "calibrated_temperature_max_C"):  # both bound the vial from the ambient up
            t = getattr(v, key)
            if t is not None and t <= amb:
                raise ValueError(f"validity.{key}: {t:g} °C is not above thermal.ambient_C {amb:g} °C (the vial "
                                 "starts at the ambient and heats while milling: every milling run would leave it)")
        if self.material.yield_stress_Pa >= 0.1 * self.material.elastic_modulus_Pa:
            raise ValueError("material.yield_stress_Pa: must be below 10 % of elastic_modulus_Pa (a yield strain "
                             "above 0.1 is not a metal)")
        if self.powder is not None and len(self.powder.materials) != len(self.powder.molar_ratio):
            raise ValueError("powder.molar_ratio: needs one number per entry of powder.materials")
        return self


class Segment(Strict):
    """One ``[[segment]]`` of a schedule file: ``hours`` (1 s to 1000 h), ``rpm`` (0: a rest) and an
    optional ``milling`` share (default 1) that leaves no milling or rest phase shorter than 6 s
    (:func:`bmctl.schedule.short_phase`). :class:`bmctl.schedule.SegmentSpec` is this class."""

    hours: HOURS
    rpm: RPM
    milling: float = Field(default=1.0, ge=0.0, le=1.0)

    @field_validator("milling", mode="after")
    @classmethod
    def _phases_long_enough(cls, milling: float, info) -> float:
        """Refuse a share that leaves a milling or rest phase shorter than :func:`bmctl.schedule.short_phase` allows."""
        from .schedule import short_phase  # bmctl.schedule imports this module

        hours, rpm = info.data.get("hours"), info.data.get("rpm")
        if hours is not None and rpm is not None:
            why = short_phase(hours, rpm, milling)
            if why:
                raise ValueError(why)
        return milling


class Schedule(Strict):
    """A schedule file: a list of (hours, rpm, milling share) segments, rpm 0 a rest, whose hours add up
    to at most :data:`~bmctl.limits.HOURS_MAX` (:func:`bmctl.schedule.long_total`).
    :class:`bmctl.schedule.ScheduleFile` is this class; :meth:`bmctl.schedule.Schedule.load` reads one."""

    name: str = ""
    segment: list[Segment] = Field(min_length=1)

    @field_validator("segment", mode="after")
    @classmethod
    def _total_within_a_batch(cls, segment: list[Segment]) -> list[Segment]:
        """Refuse segments whose hours add up to more than :data:`~bmctl.limits.HOURS_MAX`."""
        return segments_within_a_batch(segment)


def segments_within_a_batch(segment):
    """``segment`` (``[[segment]]`` tables, or None), or a ValueError (for a pydantic validator) when
    their hours add up to more than the longest batch, :data:`~bmctl.limits.HOURS_MAX`
    (:func:`bmctl.schedule.long_total`)."""
    from .schedule import long_total  # bmctl.schedule imports this module

    why = long_total(sum(s.hours for s in segment)) if segment else ""
    if why:
        raise ValueError(why)
    return segment


_BARE_KEY = re.compile(r"[A-Za-z0-9_-]{1,60}")


def _fmt_loc(loc: tuple) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            key = str(part) if _BARE_KEY.fullmatch(str(part)) else quote(str(part))  # a key as TOML would quote it
            out += ("." if out else "") + key
    return out or "(top level)"


#: a key longer than this is not compared with the known ones (no typo is that long)
SUGGEST_MAX_CHARS = 100


def close_key(key: str, known) -> str | None:
    """The known key ``key`` most likely mistypes, or None (:func:`difflib.get_close_matches`).

    Parameters
    ----------
    key : str
        The unknown key.
    known : iterable of str
        The keys that exist there.

    Examples
    --------
    >>> close_key("alpah", ["alpha", "beta"]), close_key("colour", ["alpha", "beta"])
    ('alpha', None)

    A key without its unit suffix names the one known key it starts (``s_mean`` is ``s_mean_um``,
    not the closer-spelled ``r_mean``):

    >>> close_key("s_mean", ["r_mean", "s_mean_um", "s_std_um"])
    's_mean_um'
    """
    import difflib

    if not isinstance(key, str) or len(key) > SUGGEST_MAX_CHARS:
        return None
    known = sorted(known)
    suffixed = [k for k in known if key and k.startswith(key + "_")]
    if len(suffixed) == 1:
        return suffixed[0]
    found = difflib.get_close_matches(key, known, n=1, cutoff=0.6)
    return found[0] if found else None


def did_you_mean(key, known) -> str:
    """`` (did you mean X?)`` for a key close to a known one (:func:`close_key`), else empty.

    >>> did_you_mean("s_maen_um", ["s_mean_um", "r_mean"]), did_you_mean("colour", ["r_mean"])
    (' (did you mean s_mean_um?)', '')
    """
    hint = close_key(str(key), known)
    return f" (did you mean {hint}?)" if hint else ""


def unknown_key_message(key: str, known, table: bool = False, likely=(), parent: str = "") -> str:
    """``unknown field`` (``unknown table``), with ``(did you mean X?)`` when a known key is close.

    Parameters
    ----------
    key : str
        The unknown key.
    known : iterable of str
        The keys that exist there.
    table : bool, optional
        The key names a table (``[name]``).
    likely : iterable of str, optional
        Keys searched first: the required ones left out beside it (a mistyped key is also missing).
    parent : str, optional
        The dotted name of the table holding a mistyped table, shown in the hint (``[estimator.pf]``).

    Examples
    --------
    >>> unknown_key_message("rmp", ["hours", "rpm"])
    'unknown field (did you mean rpm?)'
    >>> unknown_key_message("stochastik", ["stochastic", "thermal"], table=True)
    'unknown table (did you mean [stochastic]?)'
    >>> unknown_key_message("pff", ["pf", "kind"], table=True, parent="estimator")
    'unknown table (did you mean [estimator.pf]?)'
    """
    hint = close_key(key, likely) or close_key(key, known)
    what = "unknown table" if table else "unknown field"
    if hint is None:
        return what
    if table:
        hint = f"[{parent}.{hint}]" if parent else f"[{hint}]"
    return f"{what} (did you mean {hint}?)"


def _unwrap(ann):
    """``ann`` without Annotated and an optional None; None for a union of several types."""
    import types
    import typing

    origin = typing.get_origin(ann)
    if origin is Annotated:
        return _unwrap(typing.get_args(ann)[0])
    if origin in (typing.Union, types.UnionType):
        members = [a for a in typing.get_args(ann) if a is not type(None)]
        return _unwrap(members[0]) if len(members) == 1 else None
    return ann


def fields_at(model, loc: tuple) -> set[str]:
    """The field names of the model at ``loc`` inside ``model`` (empty when not a model there).

    Parameters
    ----------
    model : type of BaseModel or None
        The model validated.
    loc : tuple
        A location as pydantic reports it (field names and list indices).

    Examples
    --------
    >>> sorted(fields_at(Schedule, ("segment", 0)))
    ['hours', 'milling', 'rpm']
    """
    import typing

    ann = model
    for part in loc:
        ann = _unwrap(ann)
        if isinstance(part, int) and typing.get_origin(ann) is list:
            ann = typing.get_args(ann)[0]
        elif isinstance(part, str) and isinstance(ann, type) and issubclass(ann, BaseModel) \
                and part in ann.model_fields:
            ann = ann.model_fields[part].annotation
        else:
            return set()
    ann = _unwrap(ann)
    return set(ann.model_fields) if isinstance(ann, type) and issubclass(ann, BaseModel) else set()


def _first_error(errors: list[dict]) -> dict:
    """The error to report: an unknown key before anything else (a mistyped key is also a missing one)."""
    return next((e for e in errors if e["type"] == "extra_forbidden"), errors[0])


def _unknown_field_msg(e: dict, errors: list[dict], model) -> tuple[str, int]:
    """The message of an unknown key, with the missing sibling or known field it likely mistypes,
    and how many other errors that explains (1 when the hint is a missing sibling: the same typo)."""
    parent, key = tuple(e["loc"][:-1]), e["loc"][-1]
    missing = [x["loc"][-1] for x in errors if x["type"] == "missing" and tuple(x["loc"][:-1]) == parent]
    table = isinstance(e.get("input"), dict)  # a mistyped [table], not a field
    msg = unknown_key_message(key, fields_at(model, parent) if model is not None else (), likely=missing,
                              table=table, parent=".".join(p for p in parent if isinstance(p, str)))
    return msg, int(close_key(key, missing) is not None)


#: a location part pydantic adds for the member of a union that failed (``constrained-float``,
#: ``list[constrained-float]``, ``tuple[float, float]``, ``float``): not a key of the file
_UNION_MEMBER = re.compile(r"constrained-[a-z-]+|[a-z][a-z-]*\[.*\]|int|float|str|bool")


def _member_at(loc: tuple) -> int | None:
    """Where in ``loc`` the union member's name is (the last part named like one; not the first,
    a field), or None."""
    at = [i for i, part in enumerate(loc) if i and isinstance(part, str) and _UNION_MEMBER.fullmatch(part)]
    return at[-1] if at else None


def _type_mismatch(error: dict) -> bool:
    return error["type"].endswith(("_type", "_parsing"))


def merge_union_errors(errors: list[dict]) -> list[dict]:
    """``errors`` with each failed union reported once, at the value's own location.

    pydantic reports a value that fits no member of a union once per member, each under the
    member's name (``target.s_mean_um.constrained-float``, ``target.s_mean_um.list[constrained-float]``).
    Of those the errors of the first member whose type the value has are kept (a number's range,
    a window's entries); where the value has none of the types, one error names them all. The
    member's name is dropped from the location; every other error is kept as it is.

    Parameters
    ----------
    errors : list of dict
        ``pydantic.ValidationError.errors()``.

    Examples
    --------
    >>> e = [{"type": "greater_than", "loc": ("target", "d50_um", "constrained-float"), "msg": "Input should be "
    ...       "greater than 0", "input": 0.0}, {"type": "list_type", "loc": ("target", "d50_um", "list[float]"),
    ...       "msg": "Input should be a valid list", "input": 0.0}]
    >>> [(x["loc"], x["msg"]) for x in merge_union_errors(e)]
    [(('target', 'd50_um'), 'Input should be greater than 0')]
    """
    groups: dict[tuple, dict[str, list[dict]]] = {}
    for e in errors:
        i = _member_at(tuple(e["loc"]))
        if i is not None:
            groups.setdefault(tuple(e["loc"][:i]), {}).setdefault(e["loc"][i], []).append(e)
    out, done = [], set()
    for e in errors:
        i = _member_at(tuple(e["loc"]))
        if i is None:
            out.append(e)
            continue
        where = tuple(e["loc"][:i])
        if where in done:
            continue
        done.add(where)
        members = groups[where]
        fitting = [errs for errs in members.values() if not all(_type_mismatch(x) for x in errs)]
        if fitting:
            kept = fitting[0]
        else:  # none of the types: one error that names each of them
            first, *rest = (errs[0]["msg"] for errs in members.values())
            kept = [dict(members[e["loc"][i]][0], msg=" or ".join([first] + [m.removeprefix("Input should be ")
                                                                            for m in rest]))]
        for x in kept:
            j = _member_at(tuple(x["loc"]))
            out.append(dict(x, loc=tuple(x["loc"][:j]) + tuple(x["loc"][j + 1:])))
    return out


def format_validation_error(source: str, err: ValidationError, model=None) -> str:
    """One line: ``source: field: message (got value)`` for the first error.

    An unknown key is reported before any other problem, with the known key it most likely
    mistypes (``segment[0].rmp: unknown field (did you mean rpm?)``); a value that fits no member
    of a union is reported once, at its own key (:func:`merge_union_errors`).

    Parameters
    ----------
    source : str
        The file (or flag) named first.
    err : pydantic.ValidationError
    model : type of BaseModel, optional
        The model validated: its field names are the hints for an unknown key.
    """
    errors = merge_union_errors(err.errors())
    e = _first_error(errors)
    loc = _fmt_loc(tuple(p for p in e["loc"] if not (isinstance(p, str) and p.startswith("function-"))))
    msg = e["msg"]
    if msg.startswith("Value error, "):
        msg = msg[len("Value error, "):]
    explained = 0
    if e["type"] == "extra_forbidden":
        msg, explained = _unknown_field_msg(e, errors, model)
    elif e["type"] == "missing":
        msg = "required field is missing"
    elif "input" in e and not isinstance(e["input"], (dict, list)) and "got" not in msg:
        msg += f" (got {quote(e['input'])})"
    more = len(errors) - 1 - explained
    tail = f" (+{more} more problem{'s' if more > 1 else ''})" if more else ""
    if not e["loc"]:  # a whole-model check: its message starts with the field it names
        return f"{source}: {msg}{tail}"
    return f"{source}: {loc}: {msg}{tail}"


def read_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file; missing/unreadable/malformed files, anything that is not a regular
    file of a sane size (a FIFO, a device) and documents nested deeper than
    :data:`bmctl.io.MAX_DEPTH` raise InputError."""
    from .io import loads_toml, read_input_bytes

    raw = read_input_bytes(path, max_bytes=TOML_MAX_BYTES)  # as given: Path("") would be the current folder
    p = Path(path)
    try:
        text = raw.decode("utf-8-sig")  # a byte-order mark (Windows editors) is not part of the TOML
    except UnicodeDecodeError as exc:
        raise InputError(f"{p}: cannot read: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    return loads_toml(text, str(p))


def validate(model: type[T], data: dict[str, Any], source: str) -> T:
    """Validate ``data`` against ``model``; errors become one-line InputError."""
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise InputError(format_validation_error(source, exc, model)) from None


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
    from .cards import resolve_card_data

    card = validate(ModelCard, resolve_card_data(read_toml(path), str(path)), str(path))
    p = card.process
    if p.mode == "interrupted" and (p.mill_min is None or p.rest_min is None):
        raise InputError(f"{path}: process: interrupted mode needs mill_min and rest_min")
    return card


def load_schedule(path: str | Path) -> Schedule:
    """Load a schedule TOML (``[[segment]]`` tables with ``hours``, ``rpm``, optional ``milling``), held to
    the limits of :class:`Schedule`; :meth:`bmctl.schedule.Schedule.load` reads the same file into a
    :class:`bmctl.schedule.Schedule`."""
    return load(Schedule, path)


def card_schedule(card: ModelCard, hours: float | None = None, rpm: float | None = None) -> list[tuple[float, float]]:
    """The card's recipe as (hours, rpm) segments, optionally overriding hours and rpm."""
    p = card.process
    total = p.hours if hours is None else hours
    speed = p.rpm if rpm is None else rpm
    if not (HOURS_MIN <= total <= HOURS_MAX):  # bmctl.config.HOURS: bounds the number of segments below
        raise InputError(f"hours: {total:g} h is outside [1 s, {HOURS_MAX:g} h], the longest batch")
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


def with_factors(card: ModelCard, gamma_mult: float, delta_mult: float, source: str = "plant") -> ModelCard:
    """A copy of ``card`` with its contact factor gamma and parting factor delta multiplied
    (eqns 15, 20): a plant whose bonding/fracture propensities are off the card. A product the
    card does not allow (above 1 µm^-2) is an :class:`~bmctl.errors.InputError` naming ``source``
    (``plant.gamma_factor``, ...), the factor and the card field.

    Examples
    --------
    >>> card = load_card("models/alni-1to1-300rpm-lab.toml")
    >>> with_factors(card, 1.5, 0.6).stochastic.gamma_per_um2 / card.stochastic.gamma_per_um2
    1.5
    """
    d = card.model_dump()
    d["stochastic"]["gamma_per_um2"] *= gamma_mult
    d["stochastic"]["delta_per_um2"] *= delta_mult
    try:
        return type(card).model_validate(d)
    except ValidationError as exc:
        err = exc.errors()[0]
        field = str(err["loc"][-1])
        key = field.removesuffix("_per_um2")
        if key not in ("gamma", "delta"):
            raise
        mult = gamma_mult if key == "gamma" else delta_mult
        raise InputError(f"{source}.{key}_factor: {mult:g} takes the card's stochastic.{field} "
                         f"{getattr(card.stochastic, field):g} to {d['stochastic'][field]:g}: {err['msg']}") from None
