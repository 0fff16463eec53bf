"""One loop, four small protocols: mill -> sensor -> estimator -> controller -> mill.

::

    plan = controller.plan(x_est, t_h, p=p, u_prev=u_prev)      # decide
    mill.advance(rpm, hours, milling)                          # apply (in sub-steps)
    estimator.predict((rpm, milling), hours)                   # propagate the belief
    s_um, r = sensor.sample(mill, rng)                         # measure (when due)
    estimate = estimator.update(s_um, r, temperature_c=...)    # correct

:class:`ClosedLoop` composes these calls one control interval at a time
(:meth:`ClosedLoop.decide`, :meth:`ClosedLoop.apply`, :meth:`ClosedLoop.observe`, or all three
in :meth:`ClosedLoop.step`), so that a mill which is a person at a real mill, answering
``advance`` by running the mill and ``sample`` by taking a micrograph, plugs in unchanged.
:func:`run_open_loop` runs a :class:`~bmctl.schedule.Schedule` on a mill without feedback
(``bmctl whatif``). Every object carries its state as plain data (``get_state`` /
``set_state``), which :mod:`bmctl.checkpoint` writes and reads.
"""

from __future__ import annotations

import math
import numbers
import time
from dataclasses import dataclass, field
from typing import Callable, Protocol, Sequence, runtime_checkable

import numpy as np

from .checkpoint import rng_state, set_rng_state
from .errors import InputError, require_generator
from .limits import HOURS_MAX, HOURS_MIN, INPUT_ROUNDING, PHASE_MIN_MINUTES, RPM_MAX, is_rpm_milling, rpm_rounding
from .physics.constants import TIME_EPS_H

#: finest plant step within a control interval: the vial temperature is watched at this spacing (h)
SUBSTEP_H = 0.05
#: tolerance of the temperature-ceiling check (degC)
CEILING_EPS_C = 1e-9


@runtime_checkable
class Mill(Protocol):
    """The plant: a simulator (:class:`bmctl.plant.Plant`) or a person at a real mill."""

    def advance(self, rpm: float, hours: float, milling: float = 1.0) -> None:
        """Mill at ``rpm`` for ``hours * milling``, then rest for the remainder."""

    def moments(self) -> dict:
        """Population moments (``s_mean_um``, ``s_std_um``, ``r_mean``, ``r_std``) and ``temperature_c``."""

    @property
    def temperature_c(self) -> float:
        """Vial temperature now (degC)."""

    def get_state(self) -> dict:
        """The full state as plain data."""

    def set_state(self, state: dict) -> None:
        """Restore a state from :meth:`get_state`."""


@runtime_checkable
class Sensor(Protocol):
    """A measurement of the mill's powder: sizes (um) and aspect ratios of sampled particles."""

    def sample(self, mill: Mill, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """``(s_um, r)`` of one sample (a micrograph's particle table)."""


@runtime_checkable
class Estimator(Protocol):
    """A belief over the moment-model state and parameters (:class:`bmctl.estimate.ParticleFilter`)."""

    def predict(self, u, dt_h: float) -> None:
        """Propagate over ``dt_h`` hours under ``u = (rpm, milling)``."""

    def update(self, s_um, r, temperature_c: float | None = None):
        """Weigh in one sample; returns the estimate (an object with ``as_dict()``)."""

    def estimate(self):
        """The current estimate without a new measurement."""

    def get_state(self) -> dict:
        """The full state as plain data."""

    def set_state(self, state: dict) -> None:
        """Restore a state from :meth:`get_state`."""


@runtime_checkable
class Controller(Protocol):
    """Plans the input of the next interval from the estimate (:mod:`bmctl.control`)."""

    interval_h: float

    def plan(self, x_est, t_h: float, p=None, u_prev=None):
        """A :class:`bmctl.control.base.Plan`; ``plan.u_apply`` is (rpm, milling) for ``interval_h``."""

    def get_state(self) -> dict:
        """Warm-start and adaptation data as plain data (compiled solvers are rebuilt)."""

    def set_state(self, state: dict) -> None:
        """Restore a state from :meth:`get_state`."""


#: the members each protocol needs, checked when a :class:`ClosedLoop` is built
PROTOCOL_MEMBERS = {
    "mill": ("advance", "moments", "temperature_c", "get_state", "set_state"),
    "sensor": ("sample",),
    "estimator": ("predict", "update", "estimate", "get_state", "set_state"),
    "controller": ("interval_h", "plan", "get_state", "set_state"),
}


def check_protocol(obj, role: str) -> None:
    """Refuse an object that lacks a member of its protocol (:data:`PROTOCOL_MEMBERS`), naming
    the argument and what is missing.

    Parameters
    ----------
    obj : object
        The mill, sensor, estimator or controller given to :class:`ClosedLoop`.
    role : {"mill", "sensor", "estimator", "controller"}
        Which protocol it must follow.
    """
    missing = [m for m in PROTOCOL_MEMBERS[role] if not hasattr(obj, m)]
    if missing:
        raise TypeError(f"{role}: {type(obj).__name__} lacks {', '.join(missing)} of the {role.capitalize()} "
                        f"protocol (bmctl.loop.{role.capitalize()}: {', '.join(PROTOCOL_MEMBERS[role])})")


def positive_hours(value, name: str) -> None:
    """Refuse a duration that is not a finite number > 0 (h), naming it.

    Parameters
    ----------
    value : float
        The duration (h).
    name : str
        What to name in the message.
    """
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not (math.isfinite(value) and value > 0):
        raise InputError(f"{name}: must be a finite number of hours > 0 (got {value!r})")


def checked_sample(out) -> tuple:
    """The ``(s_um, r)`` a sensor returned, unchanged, or a clear error: a pair of equal-length
    1-D arrays is expected.

    Parameters
    ----------
    out : object
        What ``sensor.sample(mill, rng)`` returned.
    """
    try:
        pair = not isinstance(out, (str, bytes, dict)) and len(out) == 2
    except TypeError:
        pair = False
    if not pair:
        raise TypeError(f"sensor.sample: must return a pair (s_um, r) of equal-length 1-D arrays "
                        f"(got {type(out).__name__})")
    s_um, r = out
    shapes = np.shape(s_um), np.shape(r)
    if len(shapes[0]) != 1 or shapes[0] != shapes[1]:
        raise ValueError(f"sensor.sample: s_um and r must be 1-D arrays of one length (got shapes {shapes[0]} "
                         f"and {shapes[1]})")
    return s_um, r


#: what the loop reads of a plan's ``status`` (a :class:`bmctl.control.Status` has them all)
STATUS_MEMBERS = ("success", "fallback", "solve_ms")


def checked_plan(plan, rpm_max: float | None = None):
    """A controller's plan, unchanged, or a clear error: it needs ``u_apply`` = (rpm, milling),
    finite, rpm in [0, ``rpm_max``] and milling in [0, 1] (each within the rounding of a solver's
    bound, :data:`~bmctl.limits.INPUT_ROUNDING`, :func:`~bmctl.limits.rpm_rounding`), and a ``status``: a
    :class:`bmctl.control.Status`, or an object with its ``success``, ``fallback`` and ``solve_ms``
    (and ``line()`` when it reports a fallback or a failure).

    Parameters
    ----------
    plan : Plan
        What ``controller.plan(...)`` returned (:class:`bmctl.control.base.Plan`).
    rpm_max : float, optional
        The mill's top speed (default :data:`bmctl.limits.RPM_MAX`).
    """
    missing = [a for a in ("u_apply", "status") if not hasattr(plan, a)]
    if missing:
        raise TypeError(f"controller.plan: must return a Plan (bmctl.control.Plan) with u_apply and status; "
                        f"{type(plan).__name__} lacks {', '.join(missing)}")
    if not is_rpm_milling(plan.u_apply):  # a solver's bound violation (INPUT_ROUNDING) passes as it always has
        raise ValueError(f"controller.plan: u_apply must be (rpm, milling), finite, rpm >= 0 and milling in [0, 1] "
                         f"(got {plan.u_apply!r})")
    top = RPM_MAX if rpm_max is None else float(rpm_max)
    if float(plan.u_apply[0]) > top + rpm_rounding(top):
        raise ValueError(f"controller.plan: u_apply rpm {float(plan.u_apply[0]):g} exceeds the mill's rpm_max "
                         f"{top:g} (got {plan.u_apply!r})")
    _check_status(plan.status)
    return plan


def _check_status(st) -> None:
    """Refuse a plan status the loop cannot read (it would fail later, in an AttributeError)."""
    from .control.base import Status

    if isinstance(st, Status):
        return
    lacks = [a for a in STATUS_MEMBERS if not hasattr(st, a)]
    if not lacks and (getattr(st, "fallback") != "none" or not getattr(st, "success")) \
            and not callable(getattr(st, "line", None)):
        lacks = ["line()"]
    if lacks:
        raise TypeError(f"controller.plan: status must be a bmctl.control.Status (or have its "
                        f"{', '.join(STATUS_MEMBERS)}); {type(st).__name__} lacks {', '.join(lacks)}")


def within_range(value: float, lo: float, hi: float, tol: float, name: str) -> float:
    """``value`` clipped to [lo, hi] when it lies outside by at most ``tol`` (a solver's rounding);
    a value farther out is refused, naming ``name``.

    >>> within_range(-1e-7, 0.0, 600.0, 1e-6, "rpm"), within_range(300.0, 0.0, 600.0, 1e-6, "rpm")
    (0.0, 300.0)
    """
    v = float(value)
    if not (lo - tol <= v <= hi + tol):
        raise InputError(f"{name}: must be in [{lo:g}, {hi:g}] (got {v!r})")
    return min(max(v, lo), hi)


def estimate_vectors(est: dict) -> tuple[np.ndarray, np.ndarray]:
    """Moment-model state x (6,) and parameter multipliers p (2,) of an estimate dict; (3,) with the
    filter's ``energy_mult`` when it carries one."""
    x = np.array([est["s_mean_um"], est["s_std_um"], est["r_mean"], est["r_std"], est["temperature_c"],
                  est.get("hardening", 0.0)])
    p = [est.get("gamma_mult", 1.0), est.get("delta_mult", 1.0)]
    if "energy_mult" in est:
        p.append(est["energy_mult"])
    return x, np.array(p)


@dataclass
class LoopConfig:
    """What the loop needs beyond its four objects.

    Attributes
    ----------
    hours : float
        Batch length (h).
    sample_every_h : float
        Time between samples (h); a sample is also taken at the batch end.
    temperature_reading : bool
        The estimator also gets the vial temperature with each sample.
    ceiling_c : float or None
        Vial-temperature ceiling. The loop counts the mill sub-steps (of at most :data:`SUBSTEP_H`,
        3 min; :meth:`ClosedLoop.apply`) that end above it (``stats["violations"]``, a trial's
        ``temperature_violations``): not crossings, so a run that rises past the ceiling once and
        stays above it adds one for every sub-step it stays there.
    power_w : callable or None
        Mean mill power (W) at an rpm, for the energy tally.
    sample_feed : bool
        Also sample the feed at 0 h, before the first decision (as ``campaign sample --at-h 0``).
    """

    hours: float
    sample_every_h: float
    temperature_reading: bool = True
    ceiling_c: float | None = None
    power_w: Callable[[float], float] | None = None
    sample_feed: bool = False

    def __post_init__(self):
        positive_hours(self.hours, "hours")
        positive_hours(self.sample_every_h, "sample_every_h")
        if self.hours > HOURS_MAX + TIME_EPS_H:  # as every batch (bmctl.limits)
            raise InputError(f"hours: {self.hours:g} h is more than the longest batch ({HOURS_MAX:g} h)")


@dataclass
class StepRecord:
    """What happened in one control interval."""

    k: int
    t_h: float  # end of the interval
    rpm: float
    milling: float
    truth: dict
    estimate: dict
    sampled: int
    solve_ms: float
    status: object


@dataclass
class ClosedLoop:
    """Mill, sensor, estimator and controller composed one control interval at a time.

    The loop's own state (step, last input, last estimate, next sample time, tallies) and its
    objects' states travel together through :meth:`get_state` / :meth:`set_state`. An object
    that lacks a member of its protocol, a ``sample_rng`` that is not a generator or a
    controller ``interval_h`` that is not a positive number of hours is refused when the loop
    is built; a sensor's or controller's answer of the wrong form when it is given.

    Attributes
    ----------
    mill : Mill
        The plant or a person at a real mill.
    sensor : Sensor
        ``sample(mill, rng) -> (s_um, r)``: sizes (um) and aspect ratios of one sample.
    estimator : Estimator
        The belief (:class:`bmctl.estimate.ParticleFilter` or the UKF).
    controller : Controller
        Plans ``(rpm, milling)`` for each ``controller.interval_h`` hours.
    sample_rng : numpy.random.Generator
        The generator passed to ``sensor.sample``.
    cfg : LoopConfig
        Batch length, sampling interval and tallies.
    k : int
        Control intervals done (0 for a fresh loop).
    u_prev : tuple of 2 floats or None
        ``(rpm, milling)`` applied over the last interval.
    est : dict
        The last estimate (``Estimate.as_dict()``); empty: read from the estimator.
    next_sample_h : float
        Batch time of the next sample (h); 0: ``cfg.sample_every_h``.
    stats : dict
        Tallies (solver failures, fallbacks, energy in J, peak temperature, sub-steps ending above the ceiling).
    peak_c : float
        The highest vial temperature of the last applied interval (degC).
    """

    mill: Mill
    sensor: Sensor
    estimator: Estimator
    controller: Controller
    sample_rng: np.random.Generator
    cfg: LoopConfig
    k: int = 0
    u_prev: tuple[float, float] | None = None
    est: dict = field(default_factory=dict)
    next_sample_h: float = 0.0
    stats: dict = field(default_factory=dict)
    peak_c: float = math.nan  # the highest vial temperature of the last applied interval (degC)

    def __post_init__(self):
        for role in PROTOCOL_MEMBERS:
            check_protocol(getattr(self, role), role)
        positive_hours(self.controller.interval_h, "controller.interval_h")
        require_generator(self.sample_rng, "sample_rng")
        if not isinstance(self.cfg, LoopConfig):
            raise TypeError(f"cfg: must be a bmctl.loop.LoopConfig (got {type(self.cfg).__name__})")
        if not self.est:
            self.est = self.estimator.estimate().as_dict()
        if not self.next_sample_h:
            self.next_sample_h = self.cfg.sample_every_h
        if not self.stats:
            self.stats = {"solver_failures": 0, "fallbacks": 0, "energy_J": 0.0, "max_T": self.mill.temperature_c,
                          "violations": 0, "solve_ms": []}

    @property
    def rpm_max(self) -> float:
        """The mill's top speed: its own ``rpm_max``, its card's ``mill.rpm_max`` (a
        :class:`bmctl.plant.Plant`), else the controller's model's, else :data:`bmctl.limits.RPM_MAX`."""
        for owner, path in ((self.mill, ("rpm_max",)), (self.mill, ("card", "mill", "rpm_max")),
                            (self.controller, ("model", "rpm_max"))):
            v = owner
            for a in path:
                v = getattr(v, a, None)
            if isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v) and v > 0:
                return float(v)
        return RPM_MAX

    @property
    def steps(self) -> int:
        """Number of control intervals of the batch."""
        return interval_count(self.cfg.hours, self.controller.interval_h)

    @property
    def done(self) -> bool:
        return self.k >= self.steps

    # --- the three calls of one interval ----------------------------------------------------
    def decide(self):
        """The controller's plan at the start of interval ``k`` (tallies solver outcomes)."""
        t_h = self.k * self.controller.interval_h
        x, p = estimate_vectors(self.est)
        t0 = time.perf_counter()
        n_spread = getattr(self.controller, "spread_particles", 0)
        if n_spread:  # a plan on operable schedules: the filter's particles as its spread
            from .control.robust import particle_scenarios

            plan = self.controller.plan(x, t_h, p=p, u_prev=self.u_prev,
                                        scenarios=particle_scenarios(self.estimator, n_spread))
        elif getattr(self.controller, "n_scen", 1) > 1:  # scenario MPC: the filter's spread as further scenarios
            from .control.robust import filter_scenarios

            plan = self.controller.plan(x, t_h, p=p, u_prev=self.u_prev,
                                        scenarios=filter_scenarios(self.est, self.controller.n_scen - 1))
        else:
            plan = self.controller.plan(x, t_h, p=p, u_prev=self.u_prev)
        st = checked_plan(plan, self.rpm_max).status
        extra = getattr(plan, "extra", None)  # a controller's own plan object may have none
        binding = extra.get("binding") if isinstance(extra, dict) else None
        if binding is not None:  # the limits the first and the latest plan run against (plans on operable schedules)
            self.stats.setdefault("binding_first", [str(b) for b in binding])
            self.stats["binding_last"] = [str(b) for b in binding]
        solve_ms = st.solve_ms if st.solve_ms else (time.perf_counter() - t0) * 1e3
        fallback = st.fallback != "none"
        self.stats["solve_ms"].append(solve_ms)
        self.stats["fallbacks"] += int(fallback)
        self.stats["solver_failures"] += int(not st.success)
        if fallback or not st.success:
            self.stats.setdefault("log", []).append(f"t={t_h:g} h: {st.line()}")
        return plan, solve_ms

    def apply(self, rpm: float, milling: float, dt_h: float) -> None:
        """Run the mill for ``dt_h`` hours in sub-steps of at most :data:`SUBSTEP_H`, milling
        first (``milling * dt_h`` hours), watching the vial temperature (its highest value in
        the interval is kept as ``peak_c``); propagate the estimator.

        An rpm or milling share outside [0, :attr:`rpm_max`] or [0, 1] by no more than a
        solver's rounding (:data:`~bmctl.limits.INPUT_ROUNDING`, :func:`~bmctl.limits.rpm_rounding`) is
        applied at the bound; values in range are applied as given."""
        rpm, milling = self._in_range(rpm, milling)
        n_sub = max(1, int(math.ceil(dt_h / SUBSTEP_H)))
        mill_h = dt_h * milling
        ceiling = self.cfg.ceiling_c
        self.peak_c = self.mill.temperature_c
        for j in range(n_sub):
            a, b = j * dt_h / n_sub, (j + 1) * dt_h / n_sub
            m = max(0.0, min(b, mill_h) - a) / (b - a)
            self.mill.advance(rpm, b - a, milling=m)
            T = self.mill.temperature_c
            self.peak_c = max(self.peak_c, T)
            self.stats["max_T"] = max(self.stats["max_T"], T)
            if ceiling is not None and T > ceiling + CEILING_EPS_C:
                self.stats["violations"] += 1
        if self.cfg.power_w is not None:
            self.stats["energy_J"] += self.cfg.power_w(rpm) * mill_h * 3600.0
        self.estimator.predict((rpm, milling), dt_h)

    def observe(self, t_h: float) -> int:
        """Sample and update the estimator when a sample is due at ``t_h`` (or the batch ends);
        returns 1 if a sample was taken."""
        sampled = 0
        if t_h >= self.next_sample_h - TIME_EPS_H or t_h >= self.cfg.hours - TIME_EPS_H:
            s_um, r = checked_sample(self.sensor.sample(self.mill, self.sample_rng))
            T_read = self.mill.temperature_c if self.cfg.temperature_reading else None
            est = self.estimator.update(s_um, r, temperature_c=T_read)
            self.next_sample_h += self.cfg.sample_every_h
            sampled = 1
        else:
            est = self.estimator.estimate()
        self.est = est.as_dict()
        return sampled

    def observe_feed(self) -> None:
        """Sample the feed before anything has run (once, at the first step when
        ``cfg.sample_feed``); the estimate is updated, no interval is recorded. No vial reading
        goes with it (the vial is at the card's room temperature, as in a campaign's
        ``sample --at-h 0``)."""
        s_um, r = checked_sample(self.sensor.sample(self.mill, self.sample_rng))
        self.est = self.estimator.update(s_um, r, temperature_c=None).as_dict()
        self.stats["feed_sampled"] = True

    def step(self) -> StepRecord:
        """One control interval: decide, apply, observe (the feed first when
        ``cfg.sample_feed`` and nothing has run)."""
        if self.k == 0 and self.cfg.sample_feed and not self.stats.get("feed_sampled"):
            self.observe_feed()
        interval = self.controller.interval_h
        t_h = self.k * interval
        dt = interval_length(t_h, self.cfg.hours, interval)
        plan, solve_ms = self.decide()
        rpm, milling = self._in_range(*plan.u_apply, name="controller.plan: u_apply")
        milling = interval_share(milling, interval, dt)
        self.apply(rpm, milling, dt)
        t_new = t_h + dt
        sampled = self.observe(t_new)
        self.u_prev = (rpm, milling)
        truth = {**self.mill.moments(), "peak_temperature_c": self.peak_c}
        rec = StepRecord(self.k, t_new, rpm, milling, truth, self.est, sampled, solve_ms, plan.status)
        self.k += 1
        return rec

    def _in_range(self, rpm, milling, name: str = "") -> tuple[float, float]:
        """(rpm, milling) as floats, clipped onto [0, rpm_max] x [0, 1] within a solver's rounding;
        farther out refused (an rpm or milling that is not a finite number too), naming ``name``."""
        lead = f"{name} " if name else ""
        try:
            rpm, milling = float(rpm), float(milling)
        except (TypeError, ValueError):
            raise InputError(f"{lead}rpm, milling: must be numbers (got {rpm!r}, {milling!r})") from None
        top = self.rpm_max
        if 0.0 <= milling <= 1.0 and 0.0 <= rpm <= top:  # the usual case: as given
            return rpm, milling
        return (within_range(rpm, 0.0, top, rpm_rounding(top), f"{lead}rpm"),
                within_range(milling, 0.0, 1.0, INPUT_ROUNDING, f"{lead}milling"))

    # --- state --------------------------------------------------------------------------------
    def get_state(self) -> dict:
        """The loop and its four objects as plain data."""
        return {
            "loop": {"k": self.k, "u_prev": None if self.u_prev is None else list(self.u_prev), "est": self.est,
                     "next_sample_h": self.next_sample_h, "stats": self.stats},
            "mill": self.mill.get_state(),
            "estimator": self.estimator.get_state(),
            "controller": self.controller.get_state(),
            "sample_rng": rng_state(self.sample_rng),
        }

    def set_state(self, state: dict) -> None:
        """Restore :meth:`get_state` output onto freshly built objects."""
        lp = state["loop"]
        self.k = int(lp["k"])
        self.u_prev = None if lp["u_prev"] is None else tuple(float(v) for v in lp["u_prev"])
        self.est = dict(lp["est"])
        self.next_sample_h = float(lp["next_sample_h"])
        self.stats = dict(lp["stats"])
        self.mill.set_state(state["mill"])
        self.estimator.set_state(state["estimator"])
        self.controller.set_state(state["controller"])
        set_rng_state(self.sample_rng, state["sample_rng"])


def interval_count(hours: float, interval_h: float) -> int:
    """Control intervals of a batch of ``hours``: a remainder under a second (:data:`bmctl.limits.HOURS_MIN`)
    is no interval of its own but the end of the last one (``interval_h = 0.3333333`` over 2 h is six
    intervals, not six and one of 0.7 ms that no log could record).

    Examples
    --------
    >>> interval_count(12.0, 0.5), interval_count(2.2, 0.5), interval_count(2.0, 0.3333333)
    (24, 5, 6)
    """
    return max(1, int(math.ceil((hours - HOURS_MIN) / interval_h))) if hours > 0 else 0


def interval_length(t_h: float, hours: float, interval_h: float) -> float:
    """Length of the control interval that starts at ``t_h``: ``interval_h``, or what is left of the batch
    when that is shorter or within a second (:data:`bmctl.limits.HOURS_MIN`) longer (see :func:`interval_count`).

    Examples
    --------
    >>> interval_length(11.5, 12.0, 0.5), interval_length(2.0, 2.2, 0.5)
    (0.5, 0.20000000000000018)
    >>> round(interval_length(5 * 0.3333333, 2.0, 0.3333333), 7)   # the last one takes the 0.7 ms left
    0.3333335
    """
    left = hours - t_h
    return left if left < interval_h + HOURS_MIN else interval_h


def interval_share(milling: float, interval_h: float, dt_h: float) -> float:
    """The milling share of an applied interval of ``dt_h`` hours for a controller's ``milling``,
    a share of its nominal ``interval_h`` (``plan.u_apply``): the same milling minutes, at most
    the whole interval. Only the last interval of a batch that is not a whole number of control
    intervals is shorter; a full interval keeps the share as it is. A rest that would be left
    shorter than the shortest phase (:data:`~bmctl.limits.PHASE_MIN_MINUTES`, 6 s: a batch a few
    seconds longer than whole minutes) is milled through: no mill is switched off for seconds.

    Examples
    --------
    >>> interval_share(0.5, 0.5, 0.5)
    0.5
    >>> interval_share(1 / 3, 0.5, 0.2)   # 10 of a 30-min interval's minutes in the last 12 min
    0.8333333333333333
    >>> interval_share(0.6, 0.5, 0.3)     # 18 min: all of the last 18 min
    1.0
    >>> interval_share(1 / 3, 0.5, 10.05 / 60)   # 10 min of the last 10.05: the 3-s rest is milled
    1.0
    >>> interval_share(0.0, 0.5, 0.001)   # a rest stays a rest
    0.0
    """
    if dt_h >= interval_h - TIME_EPS_H:
        return milling
    share = min(1.0, milling * interval_h / dt_h)
    if share > 0.0 and (1.0 - share) * dt_h * 60.0 < PHASE_MIN_MINUTES * (1.0 - 1e-9):  # seconds of rest: mill on
        return 1.0
    return share


def run_interval(mill: Mill | None, estimators: Sequence[Estimator], schedule, t0_h: float,
                 t1_h: float) -> list[tuple[float, float, float]]:
    """Open loop over [t0_h, t1_h] of ``schedule``: the mill and every estimator are advanced
    through the same (rpm, milling, hours) pieces (:meth:`bmctl.schedule.Schedule.inputs_between`),
    which are returned.

    Parameters
    ----------
    mill : Mill or None
        Advanced through the pieces (None: only the estimators).
    estimators : sequence of Estimator
        Each is predicted through the same pieces.
    schedule : Schedule or sequence of (hours, rpm[, milling])
        The inputs (:func:`bmctl.schedule.as_schedule`).
    t0_h, t1_h : float
        The window of the schedule (h from its start).
    """
    from .schedule import as_schedule

    pieces = as_schedule(schedule).inputs_between(t0_h, t1_h)
    if mill is not None:
        for rpm, milling, h in pieces:
            mill.advance(rpm, h, milling)
    for est in estimators:
        for rpm, milling, h in pieces:
            est.predict((rpm, milling), h)
    return pieces


def record_times(total_h: float, every_h: float) -> np.ndarray:
    """Recording times 0, every_h, ... and the end (h)."""
    times = np.arange(0.0, total_h + TIME_EPS_H, every_h)
    if total_h - times[-1] > TIME_EPS_H:
        times = np.append(times, total_h)
    return times


def check_open_loop(segments, record_every_h) -> None:
    """Refuse a recording interval that is not a finite number of hours > 0, or a segment that is not
    (hours, rpm) with hours a finite number >= 0, naming it (:func:`run_open_loop`,
    :meth:`bmctl.plant.Plant.run_schedule`).

    Parameters
    ----------
    segments : sequence of (hours, rpm)
    record_every_h : float
    """
    positive_hours(record_every_h, "record_every_h")
    for i, seg in enumerate(segments):
        try:
            pair = len(seg) == 2
        except TypeError:
            pair = False
        if not pair or not (isinstance(seg[0], numbers.Real) and math.isfinite(seg[0]) and seg[0] >= 0):
            raise InputError(f"segments[{i}]: must be (hours, rpm) with hours a finite number >= 0 (got {seg!r})")


def run_open_loop(mill: Mill, segments: Sequence[tuple[float, float]], record_every_h: float,
                  on_record: Callable[[float, Mill], None]) -> np.ndarray:
    """Run (hours, rpm) segments on ``mill`` without feedback, calling ``on_record(t_h, mill)`` at
    every recording time (t = 0 included); returns the recording times (h from the start).

    Each recording interval is cut at the segment boundaries and every piece is one
    ``advance`` call (the same calls as :meth:`bmctl.plant.Plant.run_schedule`).

    Parameters
    ----------
    mill : Mill
        Advanced through the segments.
    segments : sequence of (hours, rpm)
        The schedule; rpm 0 is a rest.
    record_every_h : float
        Time between recordings (h); the end is recorded too.
    on_record : callable
        ``on_record(t_h, mill)`` at each recording time.
    """
    check_open_loop(segments, record_every_h)
    total = sum(h for h, _ in segments)
    times = record_times(total, record_every_h)
    bounds = np.cumsum([0.0] + [h for h, _ in segments])
    on_record(float(times[0]), mill)
    for k in range(1, times.size):
        a, b = times[k - 1], times[k]
        for (h, rpm), lo, hi in zip(segments, bounds[:-1], bounds[1:]):
            x0, x1 = max(a, lo), min(b, hi)
            if x1 > x0 + 1e-12:
                mill.advance(rpm, x1 - x0)
        on_record(float(b), mill)
    return times
