"""What every controller shares: the :class:`Plan` it returns, the :class:`Status` record,
time-varying references, the applied-input rounding and the vial-temperature peak.

The controller interface (stable; used by ``bmctl trial`` and ``bmctl whatif``)::

    ctrl = make_controller("controllers/mpc-default.toml", model)
    ctrl.set_target({"s_mean_um": 25.0})          # optional: overrides the file's target
    plan = ctrl.plan(x_est, t_h, p=None, u_prev=None)
    rpm, milling = plan.u_apply                   # apply for ctrl.interval_h hours:
                                                  # mill milling*interval_h at rpm, then rest

``x_est`` is the moment-model state (6,), ``t_h`` the batch time (h) at the start of the
interval, ``p`` the (gamma_mult, delta_mult) estimate (default (1, 1)), ``u_prev`` the
(rpm, milling) applied over the previous interval (None at the batch start).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Callable, Mapping, Sequence

import numpy as np

from ..errors import InputError, quote
from ..moments import equations as eq
from .config import NOT_NUMBERS, TARGET_KEYS, Target, check_target_dict

#: returned by Status.fallback
FALLBACKS = ("none", "shifted", "rest")


def applied_input(u, interval_h: float, round_minutes: bool = True, binary: bool = False) -> np.ndarray:
    """The input actually applied for one interval: (rpm, milling) with whole minutes of milling.

    The milling time ``milling * interval_h`` is rounded to the nearest whole minute (a
    mill timer counts minutes); ``binary`` first rounds milling to 0 or 1. An interval with
    no milling left is a rest and reported as rpm 0.

    Parameters
    ----------
    u : sequence of 2 floats
        Planned (rpm, milling) for the interval.
    interval_h : float
        Interval length (h).
    round_minutes : bool, optional
        Round the milling time to whole minutes.
    binary : bool, optional
        Round milling to 0 or 1 first (on/off mode).

    Returns
    -------
    ndarray, (2,)
        Applied (rpm, milling).

    Examples
    --------
    >>> applied_input((300.0, 0.337), 0.5)   # 10.11 min -> 10 min of 30
    array([300.        ,   0.33333333])
    """
    rpm, m = float(u[0]), float(np.clip(u[1], 0.0, 1.0))
    if binary:
        m = 1.0 if m >= 0.5 else 0.0
    if round_minutes:
        minutes = interval_h * 60.0
        whole = round(m * minutes)
        m = whole / minutes if minutes > 0 else 0.0
        m = min(m, 1.0)
    if m <= 0.0:
        return np.array([0.0, 0.0])
    return np.array([rpm, m])


def applied_input_guarded(model, x0, u, interval_h: float, ceiling_c: float, round_minutes: bool = True,
                          binary: bool = False) -> np.ndarray:
    """:func:`applied_input`, but rounding the milling time down when rounding up would push the
    peak vial temperature over ``ceiling_c`` (and above the unrounded plan's peak)."""
    a = applied_input(u, interval_h, round_minutes, binary)
    if not round_minutes or a[1] <= float(u[1]) + 1e-12:
        return a
    T_a = float(peak_temperature(model, x0[4], x0[5], a[0], a[1], interval_h))
    T_u = float(peak_temperature(model, x0[4], x0[5], float(u[0]), float(u[1]), interval_h))
    if T_a > ceiling_c and T_a > T_u + 1e-9:
        minutes = interval_h * 60.0
        m = math.floor(a[1] * minutes - 1 + 1e-9) / minutes
        return np.array([a[0], m]) if m > 0 else np.array([0.0, 0.0])
    return a


def peak_temperature(model, T0, h0, rpm, milling, dt_h, xp=np):
    """Vial temperature at the end of the milling phase of an interval (its maximum when heating).

    Same closed form as the model's step (mill ``milling * dt_h`` at rpm, then rest).
    Works with numpy arrays or casadi expressions (``xp=casadi``).

    Parameters
    ----------
    model : MomentModel
        Supplies the card's thermal constants.
    T0, h0 : float or array or casadi expression
        Vial temperature (degC) and hardening at the interval start.
    rpm, milling : float or array or casadi expression
        Input over the interval.
    dt_h : float
        Interval length (h).
    xp : module, optional
        ``numpy`` (default) or ``casadi``.
    """
    B = eq.NP if xp is np else eq.CA()
    c = model.const
    T1, _ = eq.thermal_exact(B, c, T0, h0, rpm / c.rpm_max, milling * dt_h)
    return T1


def interval_peaks(model, X, U, dt_h: float) -> np.ndarray:
    """Highest vial temperature within each interval of a trajectory: max(T at its start, T at the
    end of its milling phase) (T is monotone within the milling phase and within the rest)."""
    X = np.asarray(X, dtype=float)
    U = np.asarray(U, dtype=float).reshape(-1, 2)
    T1 = np.asarray(peak_temperature(model, X[:-1, 4], X[:-1, 5], U[:, 0], U[:, 1], dt_h), dtype=float)
    return np.maximum(X[:-1, 4], T1)


def max_milling_for_ceiling(model, T0: float, rpm: float, dt_h: float, ceiling_c: float) -> float:
    """Largest milling fraction in [0, 1] whose peak temperature stays <= the ceiling (closed form)."""
    c = model.const
    w = rpm / c.rpm_max
    T_ss = c.ambient_C + c.power_max_W * w**3 * c.cooling_time_h * 3600.0 / c.heat_capacity_J_per_K
    if T_ss <= ceiling_c:
        return 1.0
    if T0 >= ceiling_c:
        return 0.0
    # T(t) = T_ss + (T0 - T_ss) exp(-t / tau) <= ceiling  <=>  t <= tau ln((T_ss - T0) / (T_ss - ceiling))
    t = c.cooling_time_h * math.log((T_ss - T0) / (T_ss - ceiling_c))
    return float(np.clip(t / dt_h, 0.0, 1.0))


@dataclass
class Status:
    """Why a plan is what it is (logged by the trial).

    Attributes
    ----------
    controller : str
        Which controller answered (mpc, lqr, recipe).
    solver_status : str
        IPOPT's return status, or batch_done, dlqr, open-loop.
    success : bool
        The solver succeeded (or no solver was needed).
    iterations : int
        Solver iterations.
    solve_ms, solve_cpu_ms : float
        Wall and CPU time of the solve(s).
    fallback : str
        none, shifted (previous plan) or rest.
    reason : str
        Why (solver failure, retries, temperature guard, binary rounding).
    slack_max_c : float
        Largest temperature slack of the solution (degC over the ceiling).
    t_peak_max_c, t_ceiling_c : float
        Largest predicted peak temperature of the plan, and the ceiling.
    cost : float
        Objective value.
    binary_loss : float or None
        Binary on/off mode: cost(rounded) - cost(continuous).
    """

    controller: str
    solver_status: str = "n/a"
    success: bool = True
    iterations: int = 0
    solve_ms: float = 0.0  # wall time of the NLP solve(s)
    solve_cpu_ms: float = 0.0  # CPU time of this process over the same span (less sensitive to a busy machine)
    fallback: str = "none"  # "none" | "shifted" | "rest"
    reason: str = ""
    slack_max_c: float = 0.0  # largest temperature slack of the solution (degC over the ceiling)
    t_peak_max_c: float = float("nan")  # largest predicted peak temperature of the returned plan
    t_ceiling_c: float = float("nan")
    cost: float = float("nan")
    binary_loss: float | None = None  # binary on/off: cost(rounded) - cost(continuous)

    @property
    def violation(self) -> bool:
        """The returned plan is predicted to exceed the temperature ceiling (by > 0.05 degC)."""
        return bool(np.isfinite(self.t_peak_max_c) and self.t_peak_max_c > self.t_ceiling_c + 0.05)

    def as_dict(self) -> dict:
        d = asdict(self)
        d["violation"] = self.violation
        return d

    def line(self) -> str:
        """One log line."""
        s = (f"{self.controller}: {self.solver_status}, {self.iterations} it, {self.solve_ms:.0f} ms"
             f", fallback {self.fallback}")
        if self.reason:
            s += f" ({self.reason})"
        if self.slack_max_c > 1e-3:
            s += f", T slack {self.slack_max_c:.2f} °C"
        if self.binary_loss is not None:
            s += f", binary loss {self.binary_loss:.3g}"
        return s


@dataclass
class Plan:
    """A controller's answer at one decision time.

    What to run next is :attr:`u_apply` (also :attr:`rpm` and :attr:`milling`): the first
    interval's input as the mill runs it. :meth:`applied` (and :meth:`schedule`,
    :meth:`segments`, built from it) is a preview of every planned interval with its milling
    time only rounded to whole minutes; its first row is *not* always :attr:`u_apply`: the
    controller's temperature guard (milling rounded down under the ceiling), its on/off mode,
    and the mill's own limits (the rpm dial's steps, the shortest milling period and rest)
    act on :attr:`u_apply` alone. A schedule shown to the operator takes :attr:`u_apply` for
    its first interval (``bmctl campaign advise`` does).

    Attributes
    ----------
    t_h : float
        Batch time of the decision (start of the first interval).
    interval_h : float
        Interval length.
    u : ndarray, (N, 2)
        Planned (rpm, milling) per interval, as solved (continuous milling).
    x : ndarray, (N + 1, 6)
        Predicted moment-model states at the interval ends, ``x[0]`` = x_est.
    t_peak_c : ndarray, (N,)
        Predicted peak vial temperature per interval.
    u_apply : ndarray, (2,)
        The input to apply now, (rpm, milling) for ``interval_h``: ``u[0]`` with whole minutes
        of milling, then the temperature guard, the on/off mode and the mill's limits (rpm 0 =
        rest). The one to read for the next interval.
    status : Status
    extra : dict
        Controller-specific details (e.g. the LQR gain).
    """

    t_h: float
    interval_h: float
    u: np.ndarray
    x: np.ndarray
    t_peak_c: np.ndarray
    u_apply: np.ndarray
    status: Status
    extra: dict = field(default_factory=dict)

    @property
    def rpm(self) -> float:
        """The rpm to run now: ``u_apply[0]`` (0: a rest)."""
        return float(self.u_apply[0])

    @property
    def milling(self) -> float:
        """The share of ``interval_h`` to mill now, first: ``u_apply[1]``."""
        return float(self.u_apply[1])

    @property
    def times_h(self) -> np.ndarray:
        return self.t_h + self.interval_h * np.arange(self.u.shape[0] + 1)

    def applied(self, round_minutes: bool = True, binary: bool = False) -> np.ndarray:
        """All planned intervals with whole minutes of milling (N, 2) (:func:`applied_input` of each
        row of ``u``): a preview of the plan. Its first row may differ from :attr:`u_apply`, which
        alone passes the temperature guard and the mill's limits; run :attr:`u_apply`.

        Parameters
        ----------
        round_minutes : bool, optional
            Round each milling time to whole minutes.
        binary : bool, optional
            Round each milling share to 0 or 1 first.

        Returns
        -------
        ndarray, (N, 2)
            (rpm, milling) per planned interval.
        """
        return np.array([applied_input(u, self.interval_h, round_minutes, binary) for u in self.u]).reshape(-1, 2)

    def schedule(self, round_minutes: bool = True):
        """The plan as a :class:`bmctl.schedule.Schedule` (mill, then rest; equal neighbours merged),
        from :meth:`applied`: its first interval is not always :attr:`u_apply`."""
        from ..schedule import Schedule

        return Schedule.from_inputs(self.applied(round_minutes), self.interval_h)

    def segments(self, round_minutes: bool = True) -> list[tuple[float, float]]:
        """The plan as (hours, rpm) segments, rpm 0 = rest (:meth:`schedule`)."""
        return self.schedule(round_minutes).pairs()


def schedule_segments(U: np.ndarray, interval_h: float, rpm_decimals: int = 0) -> list[tuple[float, float]]:
    """(hours, rpm) segments of applied inputs per interval: mill, then rest; neighbours merged.

    Parameters
    ----------
    U : array_like, (N, 2)
        Applied (rpm, milling) per interval.
    interval_h : float
        Interval length (h).
    rpm_decimals : int, optional
        Rounding of the rpm values in the segments.
    """
    from ..schedule import Schedule

    return Schedule.from_inputs(U, interval_h, rpm_decimals).pairs()


class Reference:
    """A piecewise-constant, time-varying target on a subset of the moments.

    ``points`` are (from_h, {moment: value}); before the first point nothing is targeted
    (a constant target is one point at 0). :meth:`at` gives the target at a batch time.

    Parameters
    ----------
    points : sequence of (float, mapping)
        (from_h, {moment: value}) pairs; moments from s_mean_um, s_std_um, r_mean, r_std.
    """

    def __init__(self, points: Sequence[tuple[float, Mapping[str, float]]] = ()):
        pts = sorted(((_from_h(t), check_target_dict(dict(d), "target")) for t, d in points),
                     key=lambda p: p[0])
        self.points = pts

    @classmethod
    def make(cls, target) -> "Reference":
        """From a Reference, a dict (constant), a Target, a list of (from_h, dict), or a callable."""
        if isinstance(target, Reference):
            return target
        if target is None:
            return cls()
        if isinstance(target, Target):
            return cls([(0.0, target.as_dict())])
        if isinstance(target, Mapping):
            return cls([(0.0, dict(target))])
        if callable(target):
            return _CallableReference(target)
        if isinstance(target, (str, bytes)):  # "d50_um=45" was read as a list of characters
            raise TypeError(f"target: a dict such as {{'d50_um': 45.0}}, a list of (from_h, dict), a callable or a "
                            f"Reference (got the text {target!r}; bmctl.campaign.targets.parse reads text)")
        return cls(list(target))

    @classmethod
    def from_config(cls, cfg) -> "Reference":
        pts = []
        if cfg.target.as_dict():
            pts.append((0.0, cfg.target.as_dict()))
        for r in cfg.reference:
            pts.append((r.from_h, r.as_dict()))
        return cls(pts)

    def at(self, t_h: float) -> dict[str, float]:
        out: dict[str, float] = {}
        for t, d in self.points:
            if t <= t_h + 1e-9:
                out = d
            else:
                break
        return dict(out)

    def keys(self) -> list[str]:
        ks: list[str] = []
        for _, d in self.points:
            ks += [k for k in d if k not in ks]
        return [k for k in TARGET_KEYS if k in ks]

    def __bool__(self) -> bool:
        return any(d for _, d in self.points)


class _CallableReference(Reference):
    def __init__(self, fn: Callable[[float], Mapping[str, float]]):
        self.fn = fn
        self.points = []

    def at(self, t_h: float) -> dict[str, float]:
        return check_target_dict(dict(self.fn(t_h) or {}), "target")

    def keys(self) -> list[str]:
        return list(TARGET_KEYS)

    def __bool__(self) -> bool:
        return True


def _from_h(t) -> float:
    """A reference point's start time (h): a number (text and flags refused), as ``float`` reads it."""
    if isinstance(t, NOT_NUMBERS):
        raise InputError(f"target: from_h: not a number: {quote(t)}")
    return float(t)


def batch_end_h(t_end_h) -> float:
    """A validated batch end (h) for ``set_target(..., t_end_h)``: a finite number > 0 (not text,
    not a flag), else an InputError naming ``t_end_h``."""
    if isinstance(t_end_h, NOT_NUMBERS):
        raise InputError(f"t_end_h: must be a finite number > 0 (got {quote(t_end_h)})")
    try:
        ok = math.isfinite(t_end_h) and t_end_h > 0
    except (TypeError, ValueError):
        raise InputError(f"t_end_h: must be a finite number > 0 (got {quote(t_end_h)})") from None
    if not ok:
        raise InputError(f"t_end_h: must be a finite number > 0 (got {t_end_h})")
    return float(t_end_h)


def check_x(x_est) -> np.ndarray:
    x = np.asarray(x_est, dtype=float).reshape(-1)
    if x.shape != (6,) or not np.all(np.isfinite(x)):
        raise InputError(f"x_est: expected 6 finite numbers (got {np.asarray(x_est).tolist()!r})")
    return x


def check_p(model, p) -> np.ndarray:
    pp = model.p0() if p is None else np.asarray(p, dtype=float).reshape(-1)
    if pp.shape not in ((2,), (3,)) or not np.all(np.isfinite(pp)) or np.any(pp <= 0):
        raise InputError(f"p: expected 2 (gamma_mult, delta_mult) or 3 (and energy_mult) finite positive numbers "
                         f"(got {np.asarray(p).tolist()!r})")
    return pp


def check_gamma_delta(model, p) -> np.ndarray:
    """:func:`check_p`, then (gamma_mult, delta_mult) only: for the predictors that take those two (the
    NLP MPC, the LQR baselines); an ``energy_mult`` the filter estimates is left out."""
    return check_p(model, p)[:2]


def check_u_prev(u_prev, model=None) -> np.ndarray | None:
    """The input applied last, ``(rpm, milling)``: finite and, with ``model``, within the ranges its
    own inputs are held to (``MomentModel._check_inputs``: rpm in [0, rpm_max], milling in [0, 1]); a
    plan from 5000 rpm on a 600 rpm mill was made as if it had run."""
    if u_prev is None:
        return None
    u = np.asarray(u_prev, dtype=float).reshape(-1)
    if u.shape != (2,) or not np.all(np.isfinite(u)):
        raise InputError(f"u_prev: expected (rpm, milling) (got {np.asarray(u_prev).tolist()!r})")
    if model is not None:
        model._check_inputs(u, "u_prev")
    return u


def check_rpm_range(cfg, rpm_max_card: float) -> None:
    """Refuse a controller that leaves no speed to mill at on this mill: its lowest milling rpm
    (``bounds.rpm_min``, ``mill.rpm_min_milling``, up to the dial's step) above the highest
    (``bounds.rpm_max`` and the card's ``mill.rpm_max``, down to the step). The plans clipped the
    bounds onto each other and milled below the lowest speed, or advised one above the mill's top.

    Parameters
    ----------
    cfg : MPCConfig or LQRConfig
    rpm_max_card : float
        The card's ``mill.rpm_max``.

    Examples
    --------
    >>> from bmctl.control import load_controller
    >>> cfg = load_controller("controllers/mpc-default.toml")
    >>> check_rpm_range(cfg, 600.0)
    >>> check_rpm_range(cfg, 90.0)
    Traceback (most recent call last):
    ...
    bmctl.errors.InputError: controller mpc-default: mill.rpm_min_milling: the lowest milling speed, 100 rpm, ...
    """
    b, mill = cfg.bounds, cfg.mill
    st = float(mill.rpm_step or 0.0)
    lo_field = "mill.rpm_min_milling" if mill.rpm_min_milling >= b.rpm_min else "bounds.rpm_min"
    lo = max(float(b.rpm_min), float(mill.rpm_min_milling))
    card = float(rpm_max_card)
    hi_field = "the card's mill.rpm_max" if card <= b.rpm_max else "bounds.rpm_max"
    hi = min(float(b.rpm_max), card)
    lo_d, hi_d = (math.ceil(lo / st - 1e-9) * st, math.floor(hi / st + 1e-9) * st) if st > 0 else (lo, hi)
    if st > 0 and hi_d <= 1e-9:  # the dial's first speed above 0 is already past the top: no bound can fix that
        raise InputError(f"controller {cfg.name}: mill.rpm_step: the {st:g} rpm dial is too coarse for this mill: "
                         f"its first speed, {st:g} rpm, is above {hi_field} ({hi:g} rpm), so no speed is left to "
                         f"mill at; set mill.rpm_step to at most {hi:g} rpm")
    if lo_d <= hi_d + 1e-9:
        return
    dial = f" on its {st:g} rpm dial (mill.rpm_step)" if st > 0 and (lo_d != lo or hi_d != hi) else ""
    raise InputError(f"controller {cfg.name}: {lo_field}: the lowest milling speed, {lo_d:g} rpm, is above "
                     f"{hi_field} ({hi_d:g} rpm){dial}: no speed is left to mill at on this mill; set "
                     f"bounds.rpm_min and mill.rpm_min_milling to at most {hi_d:g} rpm")


def rpm_window(bounds, rpm_max_model: float, u_prev) -> tuple[float, float, float]:
    """(lo, hi, rpm_hi) for the first interval's rpm: bounds and the rate limit from ``u_prev``.

    A rest (rpm 0 or milling 0) carries no setpoint: the next interval may start anywhere in bounds.
    """
    lo = bounds.rpm_min
    hi = min(bounds.rpm_max, rpm_max_model)
    lo = min(lo, hi)
    if u_prev is not None and bounds.rpm_step_max is not None and u_prev[0] > 0 and u_prev[1] > 0:
        r = float(u_prev[0])
        lo2, hi2 = max(lo, r - bounds.rpm_step_max), min(hi, r + bounds.rpm_step_max)
        if lo2 > hi2:  # previous rpm outside the bounds: move toward them as fast as allowed
            lo2 = hi2 = float(np.clip(r, lo, hi))
        lo, hi = lo2, hi2
    return lo, hi, min(bounds.rpm_max, rpm_max_model)
