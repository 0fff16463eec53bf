"""Controller configurations (TOML under ``controllers/``): pydantic schemas and the loader.

Every controller file names its ``kind``:

* ``"mpc"``    -- :class:`MPCConfig`, nonlinear MPC on the moment model (bmctl/control/mpc.py)
* ``"lqr"``    -- :class:`LQRConfig`, gain-scheduled LQR with integral action (baselines.py)
* ``"recipe"`` -- :class:`RecipeConfig`, the paper's open-loop schedules (baselines.py)

Errors are one line naming the file and the field, e.g.
``controllers/x.toml: weights.terminal: Input should be greater than or equal to 0 (got -1)``.
See docs/control.md for the meaning of every field.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal, Union

import numpy as np
from pydantic import Field, field_validator, model_validator

from ..config import HOURS, MINUTES, RPM, Finite, Frac, NonNeg, Pos, Range, Strict, did_you_mean, read_toml, validate
from ..limits import HOURS_MAX, PHASE_MAX_MINUTES, RPM_MAX
from ..errors import InputError, finite_float, quote

#: moments a target may name (state components 0..3 of the moment model)
MOMENT_KEYS = ("s_mean_um", "s_std_um", "r_mean", "r_std")
#: volume-weighted D-values (laser-diffraction convention) of the size law of (s_mean, s_std)
DVALUE_KEYS = ("d50_um", "d90_um", "span")
#: everything a target may name: the moments, then the D-values (outputs of the moment model)
TARGET_KEYS = MOMENT_KEYS + DVALUE_KEYS
#: allowed range of each target key (open interval; sizes above 1 nm, the particle tables' floor)
TARGET_RANGE = {"s_mean_um": (1e-3, 1e5), "s_std_um": (0.0, 1e5), "r_mean": (0.0, 1.0), "r_std": (0.0, 0.5),
                "d50_um": (1e-3, 1e5), "d90_um": (1e-3, 1e5), "span": (0.0, 100.0)}


def check_dvalue_order(target: dict, source: str) -> None:
    """D90 above D50 where a target names both (windows: some D90 of its window above some D50 of its).

    >>> check_dvalue_order({"d50_um": 45.0, "d90_um": 40.0}, "--target")
    Traceback (most recent call last):
    ...
    bmctl.errors.InputError: --target: d90_um (40) must be above d50_um (45): no size law has D90 <= D50
    """
    if "d50_um" in target and "d90_um" in target:
        d50_lo = target_bounds(target["d50_um"])[0]
        d90_hi = target_bounds(target["d90_um"])[1]
        if d90_hi <= d50_lo:  # no D90 of the window above any D50 of its window
            raise InputError(f"{source}: d90_um ({format_target(target['d90_um'])}) must be above d50_um "
                             f"({format_target(target['d50_um'])}): no size law has D90 <= D50")


def target_value(key: str, value, source: str):
    """A validated target value: a number (point) or a window [lo, hi] (returned as a float or a (lo, hi) tuple)."""
    lo_ok, hi_ok = TARGET_RANGE[key]

    def one(v):
        if isinstance(v, bool):  # float(True) is 1.0: a flag, not a size
            raise InputError(f"{source}: {key}: not a number: {v!r}")
        x = finite_float(v, f"{source}: {key}")
        if not (lo_ok < x < hi_ok):
            raise InputError(f"{source}: {key}: must be in ({lo_ok:g}, {hi_ok:g}) (got {x:g})")
        return x

    if isinstance(value, (list, tuple)):
        if len(value) != 2:
            raise InputError(f"{source}: {key}: a window is [lo, hi] (got {len(value)} values)")
        lo, hi = one(value[0]), one(value[1])
        if lo > hi:
            raise InputError(f"{source}: {key}: window [{lo:g}, {hi:g}] has lo > hi")
        return (lo, hi) if hi > lo else lo
    return one(value)


def target_value_problem(key: str, value) -> str | None:
    """What is wrong with a target value, as :func:`target_value` says it without its
    ``<source>: <key>: `` prefix (for a message whose location names the key, ``target.<key>``).

    Parameters
    ----------
    key : str
        One of :data:`TARGET_KEYS`.
    value : float or [lo, hi]
        The value as given.

    Returns
    -------
    str or None
        None when the value is valid.

    Examples
    --------
    >>> target_value_problem("r_mean", 5.0)
    'must be in (0, 1) (got 5)'
    >>> target_value_problem("r_mean", [0.2, 0.3]) is None
    True
    """
    try:
        target_value(key, value, "target")
    except InputError as exc:
        return str(exc).split(": ", 2)[-1]
    return None


def target_bounds(value) -> tuple[float, float]:
    """(lo, hi) of a target value (a point has lo = hi)."""
    if isinstance(value, (tuple, list)):
        return float(value[0]), float(value[1])
    return float(value), float(value)


def target_centre(value) -> float:
    lo, hi = target_bounds(value)
    return 0.5 * (lo + hi)


def format_target(value) -> str:
    lo, hi = target_bounds(value)
    return f"{lo:g}" if lo == hi else f"[{lo:g}, {hi:g}]"


#: what a number given from Python may not be: text (``"55"`` is not read as 55) and flags
#: (``float(True)`` is 1.0)
NOT_NUMBERS = (str, bytes, bytearray, bool, np.bool_)


def check_target_dict(d, source: str) -> dict:
    """Validate {key: value or [lo, hi]}; returns {key: float or (lo, hi)}. A value of a known key
    (or an entry of its window) that is text or a flag is refused, not read as a number.

    >>> check_target_dict({"s_mean_um": 25, "r_mean": [0.1, 0.2]}, "target")
    {'s_mean_um': 25.0, 'r_mean': (0.1, 0.2)}
    >>> check_target_dict({"s_mean_um": "25"}, "target")
    Traceback (most recent call last):
    ...
    bmctl.errors.InputError: target: s_mean_um: not a number: '25'
    """
    if not isinstance(d, dict):
        raise InputError(f"{source}: expected a table of targets")
    for k, v in d.items():
        entries = v if isinstance(v, (list, tuple)) else (v,)
        if k in TARGET_KEYS and any(isinstance(x, NOT_NUMBERS) for x in entries):
            raise InputError(f"{source}: {k}: not a number: {quote(v)}")
    out = {}
    for k, v in d.items():
        if k not in TARGET_KEYS:
            raise InputError(f"{source}: unknown target {k!r}{did_you_mean(k, TARGET_KEYS)} (one of {', '.join(TARGET_KEYS)})")
        out[k] = target_value(k, v, source)
    check_dvalue_order(out, source)
    return out


TargetValue = Union[float, list[float]]


class Target(Strict):
    """A target on any subset of the micrograph moments and the volume-weighted D-values (absent = not
    controlled). Each is a number (a point) or ``[lo, hi]`` (a window: no cost inside it)."""

    s_mean_um: TargetValue | None = None
    s_std_um: TargetValue | None = None
    r_mean: TargetValue | None = None
    r_std: TargetValue | None = None
    d50_um: TargetValue | None = None
    d90_um: TargetValue | None = None
    span: TargetValue | None = None

    @field_validator(*TARGET_KEYS, mode="after")
    @classmethod
    def _value(cls, value, info):
        """Each value in its range (the error's location names the key: ``target.r_mean``)."""
        problem = None if value is None else target_value_problem(info.field_name, value)
        if problem is not None:
            raise ValueError(problem)
        return value

    @model_validator(mode="after")
    def _values(self):
        try:
            check_dvalue_order({k: getattr(self, k) for k in TARGET_KEYS if getattr(self, k) is not None}, "target")
        except InputError as exc:
            raise ValueError(str(exc).split(": ", 1)[-1]) from None
        return self

    def as_dict(self) -> dict:
        return {k: target_value(k, v, "target") for k, v in self.model_dump().items()
                if k in TARGET_KEYS and v is not None}


class Mill(Strict):
    """What the mill can do (enforced in ``bmctl design``, in the MPC's applied plans and in trials).

    Each milling period lasts at least ``min_mill_min`` and each rest at least ``min_rest_min``
    (minutes; 0 = no limit); a batch has at most ``max_switches`` on/off transitions (none = no
    limit); while milling, rpm >= ``rpm_min_milling`` and rpm is a multiple of ``rpm_step``.
    """

    min_mill_min: Range(0.0, PHASE_MAX_MINUTES) = 0.0  # minutes, at most a day (bmctl.limits)
    min_rest_min: Range(0.0, PHASE_MAX_MINUTES) = 0.0
    max_switches: Annotated[int, Field(ge=0, le=100_000)] | None = None
    rpm_min_milling: RPM = 0.0
    rpm_step: Range(0.0, RPM_MAX, lo_open=True) | None = None


class Robust(Strict):
    """Scenario MPC on the particle filter's spread (docs/control.md).

    ``mode = "scenario"``: the plan is shared by ``scenarios`` predictions -- the estimate and
    (gamma, delta) at the filter's 5 %/95 % quantiles (with the 95 % vial temperature); the
    tracking cost is their mean and the temperature ceiling holds for each.
    """

    mode: Literal["nominal", "scenario"] = "nominal"
    scenarios: Annotated[int, Field(ge=2, le=5)] = 3


class Objective(Strict):
    """What ``bmctl design`` optimises (docs/control.md).

    * ``"target"``: the target error plus the energy and time weights (as the MPC);
    * ``"min_time"``: the shortest batch whose final error is within ``tolerance``;
    * ``"min_energy"``: the least dissipated energy among batches within ``tolerance``.
    """

    kind: Literal["target", "min_time", "min_energy"] = "target"
    tolerance: Annotated[float, Field(gt=0, lt=1)] = 0.02  # relative error outside a window / off a point
    phases: Annotated[int, Field(ge=1, le=12)] = 4  # schedule phases (each one rpm and one mill/rest pattern)
    integer_method: Literal["relax-round", "bonmin"] = "relax-round"
    #: batch lengths tried by min_time / min_energy and the trade-off table (fractions of --hours; at
    #: least one; each batch at least one control interval long, checked where --hours is known)
    sweep: list[Annotated[float, Field(gt=0, le=1)]] = [0.25, 0.5, 0.75, 1.0]

    @field_validator("sweep", mode="after")
    @classmethod
    def _sweep_not_empty(cls, value):
        if not value:
            raise ValueError("needs at least one batch length (fractions of --hours in (0, 1], e.g. "
                             "[0.25, 0.5, 0.75, 1.0])")
        return value


class PlanSearch(Strict):
    """How plans are made (docs/control.md, "Global search").

    ``method = "search"``: every call plans the rest of the batch on operable schedules (families
    evaluated in one vectorised batch, then a local search on the same grid; the advice is the
    plan's first interval). ``"nlp"``: the multiple-shooting NLP over the horizon, its continuous
    milling shares rounded onto the mill's limits afterwards. The search settings serve
    ``bmctl design``'s global search too.
    """

    method: Literal["nlp", "search"] = "nlp"
    #: RKC substeps of the search's prediction per part of a milling period (its first 5 min, the rest)
    substeps: Annotated[int, Field(ge=1, le=16)] = 2
    #: RKC substeps of a milling period's first 5 min in the search's prediction (None: ``substeps``);
    #: ``bmctl design`` uses 8 (a burst as finely as the model's own 0.5 h step)
    onset_substeps: Annotated[int, Field(ge=1, le=32)] | None = None
    #: filter particles (a deterministic weighted selection) the closest plans are also scored on; 0: the estimate only
    spread: Annotated[int, Field(ge=0, le=1000)] = 64
    rpm_step: Annotated[float, Field(gt=0)] = 20.0  # spacing of the coarse search's rpm grid
    coarse_factor: Annotated[int, Field(ge=1, le=8)] = 2  # intervals per step of the coarse batch
    error_band: Annotated[float, Field(ge=0, lt=0.5)] = 0.002  # errors within this band count as equal
    rounds: Annotated[int, Field(ge=0, le=10)] = 1  # local-search rounds after the coarse batch
    pool: Annotated[int, Field(ge=1, le=200)] = 8  # plans scored on the spread (closest, cheapest, per family)
    pool_band: Annotated[float, Field(ge=0, lt=1)] = 0.03  # nominal error band of that pool
    #: weight of the variance a plan adds over the spread in the pool's score e^2 + risk (Var(e) - Var_rest(e));
    #: 1 = as in the open-loop expected
    #: squared error; less counts on the feedback of later plans
    risk: Annotated[float, Field(ge=0, le=10)] = 0.25
    #: when resting on is predicted outside ``[objective] tolerance``, also weigh single bursts now
    #: (then rest) in the spread-scored pool: small steps toward the target (docs/control.md, "Nudges");
    #: weighed once the mill has milled in the batch
    nudge: bool = False


class ReferencePoint(Target):
    """A time-varying reference: this target applies from ``from_h`` (batch time) on."""

    from_h: Range(0.0, HOURS_MAX)


class Bounds(Strict):
    """Input bounds and the rpm rate limit."""

    rpm_min: RPM = 100.0
    rpm_max: Range(0.0, RPM_MAX, lo_open=True) = 500.0  # the mill's rpm_max (model card) caps it further
    milling_min: Frac = 0.0
    milling_max: Frac = 1.0
    #: largest change of the rpm setpoint between consecutive intervals (rpm); none = unlimited
    rpm_step_max: Range(0.0, RPM_MAX, lo_open=True) | None = 100.0

    @model_validator(mode="after")
    def _order(self):
        if self.rpm_min > self.rpm_max:
            raise ValueError(f"rpm_min ({self.rpm_min:g}) must be <= rpm_max ({self.rpm_max:g})")
        if self.milling_min > self.milling_max:
            raise ValueError(f"milling_min ({self.milling_min:g}) must be <= milling_max ({self.milling_max:g})")
        return self


class Temperature(Strict):
    """Vial-temperature ceiling: hard, with a heavily penalised slack so the problem stays feasible."""

    ceiling_c: Range(-200.0, 4000.0, lo_open=True) = 80.0  # above the coldest ambient a card allows
    slack_weight: NonNeg = 1e3  # per degC of violation, summed over intervals (exact L1 penalty)
    slack_weight_quad: NonNeg = 10.0  # per degC^2
    slack_max_c: NonNeg | None = None  # cap on the slack (0 = a truly hard constraint; may be infeasible)
    #: relative sd of the mill's heating power against the card's before any vial reading; a campaign's
    #: next interval holds the ceiling at ``heating_z`` posterior sd above the power fitted to the readings
    heating_sd: NonNeg = 0.2
    heating_z: NonNeg = 0.0  # 0: at the fit; 1.645: at the upper 95 % (a mill whose heating is not known)


class Weights(Strict):
    """Objective weights. Target errors are relative: (y - ref) / max(|ref|, floor)."""

    stage: NonNeg = 1.0  # per hour, on the target error at every interval end up to the batch end
    terminal: NonNeg = 20.0  # on the target error at the batch end (or the horizon end)
    s_mean_um: NonNeg = 1.0
    s_std_um: NonNeg = 1.0
    r_mean: NonNeg = 1.0
    r_std: NonNeg = 1.0
    energy_per_kWh: NonNeg = 0.5  # dissipated energy: P_max (rpm/rpm_max)^3 * milling * hours
    time_per_h: NonNeg = 0.005  # per hour spent milling (machine time)
    rpm_move: NonNeg = 0.05  # per ((rpm_k - rpm_k-1) / rpm_max)^2, also from the last applied rpm
    #: per on/off transition (the operator's work), in the global search's tie-break ([plan], `bmctl design`)
    switch: NonNeg = 0.005


class Solver(Strict):
    """IPOPT options (casadi.nlpsol)."""

    max_iter: Annotated[int, Field(ge=0)] = 100
    tol: Pos = 1e-5
    acceptable_tol: Pos = 1e-3
    acceptable_iter: Annotated[int, Field(ge=1)] = 3  # consecutive acceptable iterates to stop early
    print_level: Annotated[int, Field(ge=0, le=12)] = 0
    #: Hessian of the Lagrangian: "gauss-newton" (cost and temperature curvature; the dynamics'
    #: curvature is dropped, cheap), "exact" (costly: ~3x a Jacobian per interval), or "limited-memory"
    hessian: Literal["gauss-newton", "exact", "limited-memory"] = "gauss-newton"
    #: Hessian of cold solves (first call, after reset(), `bmctl design`): far from the solution the
    #: Gauss-Newton steps cycle; the exact Hessian converges in ~30-40 iterations
    cold_hessian: Literal["gauss-newton", "exact", "limited-memory"] = "exact"
    #: compile the exact-Hessian solvers too (cold solves, exact retries) into bmctl's cache: ~15 MB of C,
    #: ~3 min of gcc -O1 in the background once per NLP; then a cold solve takes ~0.8 s instead of ~10 s
    compile_exact: bool = True
    warm_start: bool = True  # start from the shifted previous plan and its multipliers
    retry_exact: bool = True  # a failed warm solve is retried once with the exact Hessian before falling back
    #: with retry_exact: iteration cap of the warm Gauss-Newton attempt (it converges in a few iterations
    #: when the target is reachable -- small residuals -- and cycles when it is not)
    gn_max_iter: Annotated[int, Field(ge=1)] = 12
    max_wall_s: Pos | None = None  # IPOPT max_wall_time
    #: Gauss-Newton only: proximal term on the scaled inputs in the approximate Hessian (shapes the
    #: steps, not the solution); without it the reduced Hessian is singular and IPOPT cycles
    gn_regularization: NonNeg = 0.1
    #: expand the NLP to casadi SX before handing it to IPOPT: faster evaluations (~40 % off a warm
    #: L-BFGS solve) for a one-off build cost of seconds per solver. "warm": only the warm solver
    #: with an approximate Hessian (built once per controller, used every interval; the
    #: exact-Hessian graph takes ~20 s to expand, so cold solves and exact retries are not); "all"; "none"
    expand: Literal["none", "warm", "all"] = "none"
    #: RKC substeps per interval of the MPC's prediction (default: the moment model's, <= 1/16 h
    #: each); fewer substeps with more stages are as stable and cheaper (docs/control.md)
    substeps: Annotated[int, Field(ge=1, le=64)] | None = None
    #: threads that run `bmctl design`'s relaxed starts side by side (default: the CPUs this process
    #: may use, at most the number of starts); each start has its own solver, so the design is the
    #: same for any number
    design_threads: Annotated[int, Field(ge=1)] | None = None


class OnOff(Strict):
    """How on/off milling is handled (docs/control.md)."""

    #: "fraction": the milling fraction is continuous (applied rounded to whole minutes);
    #: "binary": after solving, milling is rounded to {0, 1} per interval (the loss is reported)
    mode: Literal["fraction", "binary"] = "fraction"
    resolve: bool = True  # binary: re-optimise rpm with the rounded milling pattern fixed
    round_minutes: bool = True  # applied milling time is a whole number of minutes


class Adaptation(Strict):
    """Correction of the MPC's prediction from the estimate's own history (docs/control.md).

    At every call the controller compares the estimate with what the moment model predicted
    for it from the previous estimate and the applied input (they differ after a micrograph
    sample). ``mode``:

    * "none": no correction;
    * "gain": per particle moment j the MPC predicts x_j + g_j (F_j(x, u, p) - x_j); g_j is a
      recursive least-squares ratio (with ``forgetting``) of the observed to the predicted
      relative changes, with a prior of 1 worth one interval of ``prior_rel_change``, clipped
      to [gain_min, gain_max];
    * "bias": offset-free MPC: the MPC predicts F(x, u, p) + d, with d the exponentially
      weighted mean (weight ``forgetting`` on the old value) of the per-interval discrepancies.
    """

    mode: Literal["none", "gain", "bias"] = "none"
    forgetting: Annotated[float, Field(gt=0.0, le=1.0)] = 0.9  # per control interval
    prior_rel_change: Pos = 0.03
    gain_min: Pos = 0.2
    gain_max: Pos = 3.0


class _Common(Strict):
    name: str = ""
    description: str = ""
    interval_h: Range(1 / 60, 24.0) = 0.5  # control interval, a minute to a day (called once per interval)
    batch_hours: HOURS | None = None  # batch length; default: the model card's process.hours
    target: Target = Target()
    reference: list[ReferencePoint] = []
    mill: Mill = Mill()


class MPCConfig(_Common):
    """Nonlinear MPC on the moment model (multiple shooting, IPOPT)."""

    kind: Literal["mpc"]
    horizon: Annotated[int, Field(ge=1, le=200)] = 8
    bounds: Bounds = Bounds()
    temperature: Temperature = Temperature()
    weights: Weights = Weights()
    solver: Solver = Solver()
    onoff: OnOff = OnOff()
    adaptation: Adaptation = Adaptation()
    robust: Robust = Robust()
    objective: Objective = Objective()
    plan: PlanSearch = PlanSearch()


class LQRTuning(Strict):
    """Velocity-form LQR on rpm with integral action on one moment (re-linearised every interval)."""

    #: the moment with integral action (a state of the moment model); default: the first moment the target names
    track: Literal["s_mean_um", "s_std_um", "r_mean", "r_std"] | None = None
    q_error: Pos = 1.0  # on the integrated relative error of the tracked moment
    q_dx: NonNeg = 1e-3  # on the state increments (scaled)
    r_du: Pos = 1.0  # on the rpm increments (rpm / rpm_max)
    milling: Frac = 1.0  # nominal milling fraction (the temperature guard may lower it)
    rpm_start: Range(0.0, RPM_MAX, lo_open=True) = 300.0  # rpm of the first interval when no previous input is known

    @field_validator("track", mode="before")
    @classmethod
    def _track_a_moment(cls, value):
        if isinstance(value, str) and value in DVALUE_KEYS:  # an output of the moment model, not one of its states
            raise ValueError(f"a D-value is not a state of the moment model: an LQR tracks a moment "
                             f"({', '.join(MOMENT_KEYS)}); a D-value target is for the MPC")
        return value


class LQRConfig(_Common):
    kind: Literal["lqr"]
    bounds: Bounds = Bounds()
    temperature: Temperature = Temperature()  # only ceiling_c is used (the guard)
    lqr: LQRTuning = LQRTuning()
    round_minutes: bool = True
    #: "guard": the milling fraction is lowered so the predicted peak stays under the ceiling (as before);
    #: "clip": milling stays at its nominal value and rpm is clipped to the highest that keeps the ceiling
    ceiling_mode: Literal["guard", "clip"] = "guard"


class RecipeConfig(_Common):
    """An open-loop recipe: rpm, continuous or ``mill_min`` on / ``rest_min`` off cycles."""

    kind: Literal["recipe"]
    interval_h: Range(1 / 60, 24.0) | None = None  # default: one mill/rest cycle, or 0.5 h when continuous
    rpm: Range(0.0, RPM_MAX, lo_open=True)
    mill_min: MINUTES | None = None  # 6 s to a day (bmctl.limits), as a card's process
    rest_min: MINUTES | None = None
    round_minutes: bool = True

    @model_validator(mode="after")
    def _cycle(self):
        if (self.mill_min is None) != (self.rest_min is None):
            raise ValueError("mill_min and rest_min go together (both or neither)")
        if self.mill_min is not None and self.interval_h is None and (self.mill_min + self.rest_min) / 60 > 24.0:
            raise ValueError(f"rest_min: a cycle of {self.mill_min + self.rest_min:g} min is longer than the "
                             "longest control interval (24 h); give interval_h")
        return self


ControllerConfig = Union[MPCConfig, LQRConfig, RecipeConfig]


def check_ceiling(cfg, card, source: str, field: str = "temperature.ceiling_c") -> None:
    """Refuse a vial-temperature ceiling at or below the card's ambient temperature (where the
    controller meets the card: a resting vial is already at the ambient, so no batch keeps under it).

    Parameters
    ----------
    cfg : ControllerConfig
        A controller without a ``[temperature]`` table (a recipe) passes.
    card : ModelCard
        The card the controller runs on (its ``thermal.ambient_C``).
    source : str
        The file that gave the ceiling (the controller's, or a scenario's), named in the message.
    field : str, optional
        The setting that gave the ceiling (e.g. a scenario's ``temperature_max_c`` that overrode the file's).

    Examples
    --------
    >>> from types import SimpleNamespace as NS
    >>> card = NS(thermal=NS(ambient_C=25.0))
    >>> cfg = validate_controller({"kind": "mpc", "temperature": {"ceiling_c": 60}}, "c.toml")
    >>> check_ceiling(cfg, card, "c.toml")
    >>> cfg.temperature.ceiling_c = 20.0
    >>> check_ceiling(cfg, card, "c.toml")
    Traceback (most recent call last):
    ...
    bmctl.errors.InputError: c.toml: temperature.ceiling_c: 20 °C is not above the card's ambient temperature (thermal.ambient_C = 25 °C): a resting vial is already at the ambient
    """
    temperature = getattr(cfg, "temperature", None)
    if temperature is None:
        return
    ambient = float(card.thermal.ambient_C)
    if temperature.ceiling_c <= ambient:
        raise InputError(f"{source}: {field}: {temperature.ceiling_c:g} °C is not above the card's "
                         f"ambient temperature (thermal.ambient_C = {ambient:g} °C): a resting vial is already at "
                         "the ambient")
KINDS: dict[str, type] = {"mpc": MPCConfig, "lqr": LQRConfig, "recipe": RecipeConfig}


def validate_controller(data: dict[str, Any], source: str) -> ControllerConfig:
    """Validate a controller table (dispatch on ``kind``); errors are one-line InputError.

    Parameters
    ----------
    data : dict
        The parsed TOML table.
    source : str
        File name used in error messages.
    """
    if not isinstance(data, dict):
        raise InputError(f"{source}: expected a table")
    kind = data.get("kind")
    if kind is None:
        raise InputError(f"{source}: kind: required field is missing (one of {', '.join(KINDS)})")
    if not isinstance(kind, str) or kind not in KINDS:
        raise InputError(f"{source}: kind: unknown controller kind {kind!r} (one of {', '.join(KINDS)})")
    cfg = validate(KINDS[kind], data, source)
    for i, r in enumerate(cfg.reference):
        if not r.as_dict():
            raise InputError(f"{source}: reference[{i}]: names no moment (one of {', '.join(TARGET_KEYS)})")
    times = [r.from_h for r in cfg.reference]
    if times != sorted(times):
        raise InputError(f"{source}: reference: from_h must be increasing")
    bounds = getattr(cfg, "bounds", None)
    if bounds is not None and cfg.mill.rpm_min_milling > bounds.rpm_max:  # the mill could never mill
        raise InputError(f"{source}: mill.rpm_min_milling: {cfg.mill.rpm_min_milling:g} rpm is above "
                         f"bounds.rpm_max ({bounds.rpm_max:g} rpm): no rpm is allowed while milling")
    step = cfg.mill.rpm_step
    # the dial's first speed above 0 past the top (as check_rpm_range rounds): only 0 rpm, a rest, is left
    if bounds is not None and step is not None and bounds.rpm_max / step < 1 - 1e-9:
        raise InputError(f"{source}: mill.rpm_step: {step:g} rpm is above bounds.rpm_max ({bounds.rpm_max:g} rpm): "
                         f"the dial is too coarse, no speed on it is allowed while milling; set mill.rpm_step to "
                         f"at most {bounds.rpm_max:g} rpm")
    if cfg.kind == "lqr" and not bounds.milling_min <= cfg.lqr.milling <= bounds.milling_max:
        raise InputError(f"{source}: lqr.milling: {cfg.lqr.milling:g} is outside [bounds.milling_min, "
                         f"bounds.milling_max] = [{bounds.milling_min:g}, {bounds.milling_max:g}]")
    if cfg.kind == "lqr":  # the file's own target and reference (a caller's set_target replaces them)
        points = ([(0.0, cfg.target.as_dict())] if cfg.target.as_dict() else []) + \
            [(r.from_h, r.as_dict()) for r in cfg.reference]
        fields = "/".join(f for f, given in (("target", cfg.target.as_dict()), ("reference", cfg.reference)) if given)
        check_lqr_track(cfg.lqr.track, points, f"{source}: {fields}", source)
    return cfg


def check_lqr_track(track: str | None, target, source: str, controller: str) -> None:
    """Refuse a target an LQR cannot track: one that never names the tracked moment (``lqr.track``),
    or, with ``lqr.track`` unset, one that names only D-values at some time.

    The LQR's integral action is on one state of the moment model (a moment, not a D-value, which
    is an output of those states). Without a target on it the LQR holds its rpm; a reference that
    names the tracked moment from some time on is fine (rpm is held before), one that never names
    it would hold rpm the whole batch.

    Parameters
    ----------
    track : str or None
        ``lqr.track``; None: at each time, the first moment the target names.
    target : mapping or sequence of (float, mapping)
        A constant target, or the reference's (from_h, target) points.
    source : str
        The file and field (or flag) that gave the target, named first in the message.
    controller : str
        The controller (its file), named with ``lqr.track``.

    Raises
    ------
    InputError
        One line naming the target's keys and the tracked moment.

    Examples
    --------
    >>> check_lqr_track("s_mean_um", {"s_mean_um": 45.0, "r_mean": 0.05}, "--target", "c.toml")
    >>> check_lqr_track(None, [(0.0, {"r_mean": 0.05}), (6.0, {"s_mean_um": 40.0})], "c.toml: reference", "c.toml")
    >>> check_lqr_track("s_mean_um", {"d50_um": 45.0}, "sc.toml: target", "c.toml")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    bmctl.errors.InputError: sc.toml: target: names d50_um, never s_mean_um, the moment the LQR tracks (lqr.track in c.toml): ...
    >>> check_lqr_track(None, {"d50_um": 45.0}, "--target", "c.toml")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    bmctl.errors.InputError: --target: names only D-values (d50_um), and an LQR tracks a moment ...
    """
    if track is not None and track not in MOMENT_KEYS:
        raise InputError(f"{controller}: lqr.track: {track} is not a state of the moment model: an LQR tracks a "
                         f"moment ({', '.join(MOMENT_KEYS)})")
    points = [(0.0, dict(target))] if hasattr(target, "keys") else [(float(t), dict(d)) for t, d in target]
    points = [(t, d) for t, d in points if d]
    if not points:  # nothing targeted: the callers that need a target refuse its absence themselves
        return
    named = [k for k in TARGET_KEYS if any(k in d for _, d in points)]
    if track is not None:
        if track in named:
            return
        moments = [k for k in named if k in MOMENT_KEYS]
        instead = (f" or set lqr.track to {' or '.join(moments)}" if moments
                   else " (an LQR tracks a moment: a D-value target is for the MPC)")
        raise InputError(f"{source}: names {', '.join(named)}, never {track}, the moment the LQR tracks (lqr.track in "
                         f"{controller}): it would hold its rpm the whole batch; give a target on {track}{instead}")
    for t, d in points:
        if not any(k in d for k in MOMENT_KEYS):  # the first key the target names would be a D-value
            keys = ", ".join(k for k in TARGET_KEYS if k in d)
            when = f" from {t:g} h" if len(points) > 1 else ""
            raise InputError(f"{source}: names only D-values ({keys}){when}, and an LQR tracks a moment of the moment "
                             f"model (lqr.track unset in {controller}: the first moment the target names); give a "
                             f"target on one of {', '.join(MOMENT_KEYS)}, or use an MPC")


def check_dwell_interval(cfg, source: str) -> None:
    """Refuse a minimum milling period or rest longer than the control interval where the applied
    intervals go one by one through :class:`bmctl.control.mill.MillGuard` (the LQR, the NLP MPC):
    it keeps the limits within an interval, so a merged period of whole intervals could end short.

    Parameters
    ----------
    cfg : ControllerConfig
        A recipe, or an MPC that plans on operable schedules (``[plan] method = "search"``), passes.
    source : str
        The controller's file, named in the message.
    """
    if cfg.kind == "recipe" or (cfg.kind == "mpc" and cfg.plan.method == "search"):
        return
    dt_min = float(cfg.interval_h) * 60.0
    for name in ("min_mill_min", "min_rest_min"):
        v = getattr(cfg.mill, name)
        if v > dt_min + 1e-9:
            raise InputError(f"{source}: mill.{name}: {v:g} min is longer than the control interval "
                             f"(interval_h = {cfg.interval_h:g} h = {dt_min:g} min): the {cfg.kind} applies one "
                             f"interval at a time and cannot keep it; lengthen interval_h"
                             + (' or plan with [plan] method = "search"' if cfg.kind == "mpc" else ""))


def load_controller(path: str | Path) -> ControllerConfig:
    """Read and validate a controller TOML (``controllers/*.toml``).

    Parameters
    ----------
    path : path-like
        The TOML file.
    """
    return validate_controller(read_toml(path), str(path))


def parse_target(text: str, source: str = "--target") -> dict:
    """Parse ``"s_mean_um=25,r_mean=0.05"`` (points) or ``"d50_um=40:50"`` (a window) into a target dict.

    Parameters
    ----------
    text : str
        Comma-separated ``key=value`` or ``key=lo:hi`` pairs; keys from :data:`TARGET_KEYS`.
    source : str, optional
        Flag or file named in error messages.

    Returns
    -------
    dict
        {key: float (point) or (lo, hi) (window)}.
    """
    out: dict = {}
    items = [t.strip() for t in str(text).split(",") if t.strip()]
    if not items:
        raise InputError(f"{source}: empty target (expected e.g. s_mean_um=25,r_mean=0.05 or d50_um=40:50)")
    for item in items:
        if "=" not in item:
            raise InputError(f"{source}: expected key=value, got {item!r}")
        k, v = (s.strip() for s in item.split("=", 1))
        if k not in TARGET_KEYS:
            raise InputError(f"{source}: unknown target {k!r}{did_you_mean(k, TARGET_KEYS)} (one of {', '.join(TARGET_KEYS)})")
        if k in out:
            raise InputError(f"{source}: {k} given twice")
        parts = [p.strip() for p in v.split(":")]
        if len(parts) > 2:
            raise InputError(f"{source}: {k}: expected a number or lo:hi (got {v!r})")
        out[k] = target_value(k, parts if len(parts) == 2 else parts[0], source)
    check_dvalue_order(out, source)
    return out
