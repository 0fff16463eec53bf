"""Global search over operable schedules: thousands of candidates evaluated in one vectorised batch
on the moment model, then a local search on the same operable grid.

A schedule here is what the mill can run, interval by interval on the controller's grid
(``interval_h``; the last interval ends at the batch end): in interval k the mill runs
``mill_min[k]`` whole minutes at ``rpm[k]``, then rests. Every candidate is built by a
*family* (:data:`FAMILIES`) and is checked over the whole horizon against the mill's limits:

* each merged milling period lasts at least ``min_mill_min`` and each rest at least
  ``min_rest_min`` (a period still open at the batch end, and the period already logged when the
  search starts, are not checked);
* the on/off transitions, with those already used, fit ``max_switches``;
* rpm on the dial (``rpm_step``), within ``[max(rpm_min, rpm_min_milling), min(rpm_max, card)]``,
  changed by at most ``rpm_step_max`` between consecutive milling intervals (a whole rest
  interval carries no setpoint): a family's rpm is approached at that rate;
* the vial-temperature peak, the closed form of eq. (6) at the end of every milling phase
  (:func:`bmctl.moments.equations.thermal_exact`), under the ceiling in every scenario.

Families (one parameter row ``rA, MA, jA, kA, oA, rB, MB, jB, cap`` each): a phase A of ``kA``
intervals at rpm ``rA`` in cycles of ``jA`` intervals milling ``MA`` minutes per cycle (milling
first; ``MA = jA x interval`` is continuous milling; ``oA`` intervals of the first cycle already
passed), then a phase B the same way, and a cap on
the total milling minutes after which the mill rests to the end. ``constant`` is one continuous
phase with a cap (mill at one rpm for a given time, then rest); ``cycled`` one phase of
rpm x duty x cycle length; ``two-phase`` a continuous phase then a continuous or cycled one at
another rpm.

Evaluation (:func:`evaluate`): the moment model's own step (:func:`bmctl.moments.equations.step`,
eqns (15)-(20), mill then rest; the RKC substeps of ``[plan] substeps``) on numpy arrays of
candidates x scenarios. Candidates that share their first intervals share those states: each
interval is integrated once per distinct prefix (a prefix tree), so a family of caps costs little
more than its longest member. Scoring (:func:`select`): under the ceiling in every scenario
first, then the nominal relative target error (the estimate's own prediction), ties within
``[plan] error_band`` broken by the error over all scenarios (the filter's spread), then by the
energy, milling-time and switch costs of ``[weights]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..limits import HOURS_MIN
from ..moments import equations as eq
from .config import target_bounds, target_centre
from .outputs import ERR_FLOOR, output_values

#: names of the columns of a parameter row
PARAMS = ("rA", "MA", "jA", "kA", "oA", "rB", "MB", "jB", "cap")
#: schedule families of the coarse search (the refinement moves within and between them)
FAMILIES = ("rest", "constant", "cycled", "two-phase", "previous")
#: no cap on the total milling minutes
NO_CAP = 1e9
#: candidates within the error band scored on every scenario of the filter's spread (the cheapest first)
POOL = 16
#: added to the relative error of a plan that rests now and mills later: a plan that mills now ranks
#: first unless resting first (e.g. to cool the vial) brings it this much closer (an advice is not a
#: rest that its successors could keep postponing)
DEFER_PENALTY = 0.005
#: weight of the secondary cost (energy, milling time, switches) in the pool's score
RISK_COST = 1e-4
#: a candidate whose predicted peak is above the ceiling by more than this (degC) is over it
CEILING_TOL_C = 0.05
#: a candidate over the ceiling that comes this much closer (relative error) than the plan is named
#: in the plan's binding limits: the ceiling is what keeps the plan from it
CLOSER_OVER_CEILING = 0.005
#: cycle lengths of the ``cycled`` family, in steps of the search grid
CYCLE_STEPS = (1, 2, 3, 4, 6, 8)
#: on a grid of steps under 30 min the cycles of 30 min to 4 h (what :data:`CYCLE_STEPS` gives on a
#: 30-min grid) are searched too, and the ``two-phase`` family's second phase also mills 30 min in
#: 1 h and 1.5 h cycles: short intervals do not shrink the cycles under the dwell minimums
SHORT_STEP_MIN = 30.0
CYCLE_MIN = (30.0, 60.0, 90.0, 120.0, 180.0, 240.0)


@dataclass(frozen=True)
class Grid:
    """The interval grid from ``t0_h`` to the batch end.

    Attributes
    ----------
    t0_h : float
        Start of the first interval (h).
    interval_min : float
        Nominal interval length (min).
    lengths_min : ndarray, (K,)
        Length of each interval (min); the last may be shorter (batch end).
    """

    t0_h: float
    interval_min: float
    lengths_min: np.ndarray

    @property
    def K(self) -> int:
        return int(self.lengths_min.size)

    @property
    def total_min(self) -> float:
        return float(self.lengths_min.sum())


def make_grid(t0_h: float, t_end_h: float, interval_h: float) -> Grid:
    """Intervals of ``interval_h`` from ``t0_h`` to ``t_end_h`` (the last one shortened), in minutes.

    Parameters
    ----------
    t0_h, t_end_h : float
        Start and batch end (h).
    interval_h : float
        Control interval (h).

    Examples
    --------
    >>> make_grid(11.0, 12.0, 0.5).lengths_min.tolist()
    [30.0, 30.0]
    >>> make_grid(0.0, 1.2, 0.5).lengths_min.tolist()
    [30.0, 30.0, 12.0]
    """
    step = interval_h * 60.0
    rem = max(0.0, (t_end_h - t0_h) * 60.0)
    rem = round(rem, 6)
    # a remainder under a second ends the last interval (bmctl.loop.interval_count)
    K = max(1, int(math.ceil((rem - HOURS_MIN * 60.0) / step))) if rem > 1e-9 else 0
    lengths = np.full(K, step)
    if K:
        lengths[-1] = rem - step * (K - 1)
    return Grid(float(t0_h), float(step), lengths)


@dataclass(frozen=True)
class Limits:
    """What the mill allows (from a controller's ``[bounds]``, ``[mill]`` and ``[temperature]``).

    Attributes
    ----------
    rpm_lo, rpm_hi : float
        Lowest and highest milling rpm (on the dial).
    rpm_step : float
        The dial's step (1 when none).
    step_max : float or None
        Largest rpm change between consecutive milling intervals.
    min_mill, min_rest : float
        Shortest milling period and rest (min).
    max_switches : int or None
        On/off transitions per batch.
    ceiling_c : float
        Vial-temperature ceiling (degC).
    power : float
        The mill's heating power relative to the card's (fitted to the vial readings by
        :func:`fit_power`; 1 without readings): the ceiling is checked with it.
    power_first : float or None
        The heating power at which the first interval's ceiling is checked (the upper bound of
        :func:`power_bound`: it runs before the next reading narrows the fit; the later intervals
        are re-planned with that reading). None: ``power``.
    """

    rpm_lo: float
    rpm_hi: float
    rpm_step: float
    step_max: float | None
    min_mill: float
    min_rest: float
    max_switches: int | None
    ceiling_c: float
    power: float = 1.0
    power_first: float | None = None


def limits_of(cfg, model) -> Limits:
    """The :class:`Limits` of an MPC configuration on a model's mill.

    Parameters
    ----------
    cfg : MPCConfig
    model : MomentModel
    """
    from .base import check_rpm_range

    check_rpm_range(cfg, model.rpm_max)  # no speed left to mill at: refused, not clipped onto each other
    mill, b = cfg.mill, cfg.bounds
    st = float(mill.rpm_step or 1.0)
    hi = min(b.rpm_max, model.rpm_max)
    hi = math.floor(hi / st + 1e-9) * st
    lo = max(b.rpm_min, mill.rpm_min_milling, st)
    lo = min(math.ceil(lo / st - 1e-9) * st, hi)
    return Limits(float(lo), float(hi), st, None if b.rpm_step_max is None else float(b.rpm_step_max),
                  float(mill.min_mill_min), float(mill.min_rest_min), mill.max_switches,
                  float(cfg.temperature.ceiling_c))


@dataclass
class Carry:
    """How the mill stands when the search starts (from the log or the controller's own record).

    Attributes
    ----------
    state : int
        -1 nothing run yet, 0 resting, 1 milling.
    run_min : float
        Minutes spent in that state so far.
    rpm : float or None
        rpm of the last interval when it milled (the rate limit starts from it).
    switches : int
        On/off transitions used so far.
    check_open : bool
        Whether the period open when the search starts counts toward the dwell minimums (its
        ``run_min`` logged plus the plan's continuation): a plan may then not end a logged rest or
        milling period short. False excepts it (:func:`operable`); the planner checks its chosen plan
        with it and searches again with it where that plan would end the period short.
    """

    state: int = -1
    run_min: float = 0.0
    rpm: float | None = None
    switches: int = 0
    check_open: bool = True

    def rests_on(self, lim: "Limits") -> bool:
        """Whether the first interval must rest: a checked open rest is under the minimum rest (with
        milling first in each interval, milling in it would end the rest now).

        Examples
        --------
        >>> from bmctl.control.search import Limits
        >>> lim = Limits(0.0, 500.0, 10.0, None, 5.0, 5.0, None, 80.0)
        >>> Carry(state=0, run_min=1.0).rests_on(lim), Carry(state=0, run_min=1.0, check_open=False).rests_on(lim)
        (True, False)
        """
        return bool(self.check_open and self.state == 0 and self.run_min < lim.min_rest - 1e-6)

    @classmethod
    def from_history(cls, history) -> "Carry":
        """From logged intervals ``(hours, rpm, milling)`` (mill first, then rest), oldest first.

        Parameters
        ----------
        history : sequence of (float, float, float)

        Examples
        --------
        >>> c = Carry.from_history([(0.5, 300, 1.0), (0.5, 300, 0.5)])
        >>> (c.state, c.run_min, c.rpm, c.switches)
        (0, 15.0, 300.0, 1)
        """
        c = cls()
        for row in history:
            hours, rpm, m = row[:3]
            L = float(hours) * 60.0
            a = round(float(m) * L) if rpm > 0 else 0.0
            a = min(a, L)
            if a > 0:
                if c.state == 1:
                    c.run_min += a
                else:
                    c.switches += int(c.state == 0)
                    c.state, c.run_min = 1, a
            if L - a > 1e-9:
                if c.state == 1:
                    c.switches += 1
                    c.state, c.run_min = 0, L - a
                else:
                    c.state, c.run_min = 0, c.run_min + (L - a) if c.state == 0 else L - a
            c.rpm = float(rpm) if a > 0 else None
        return c


# --- candidates ------------------------------------------------------------------------------------
def expand(params: np.ndarray, grid: Grid, lim: Limits, carry: Carry | None = None):
    """Per-interval rpm and milling minutes of parameter rows (see the module docstring).

    Parameters
    ----------
    params : ndarray, (N, 9)
        Rows ``rA, MA, jA, kA, oA, rB, MB, jB, cap``.
    grid : Grid
    lim : Limits
    carry : Carry, optional

    Returns
    -------
    (ndarray, ndarray)
        rpm (N, K) (0 where the interval only rests) and milling minutes (N, K), whole minutes or the
        whole interval (an interval of 19.8 min milled throughout mills 19.8 min, not 19 and a rest).
    """
    P = np.atleast_2d(np.asarray(params, dtype=float))
    N, K = P.shape[0], grid.K
    L = grid.interval_min
    k = np.arange(K)[None, :]
    rA, MA, jA, kA, oA, rB, MB, jB, cap = (P[:, i:i + 1] for i in range(9))
    inA = k < kA
    pos = np.where(inA, np.mod(k + oA, np.maximum(jA, 1)), np.mod(k - kA, np.maximum(jB, 1)))
    M = np.where(inA, MA, MB)
    minutes = np.clip(M - L * pos, 0.0, L)
    minutes = np.minimum(minutes, grid.lengths_min[None, :])
    full = minutes >= grid.lengths_min[None, :] - 1e-9  # milling throughout: the interval's own length
    minutes = np.where(full, grid.lengths_min[None, :], np.floor(minutes + 1e-9))  # else whole minutes
    if carry is not None and K > 0 and carry.rests_on(lim):
        minutes[:, 0] = 0.0  # a logged rest under the minimum runs on through the first interval
    before = np.cumsum(minutes, axis=1) - minutes
    minutes = np.clip(np.minimum(minutes, cap - before), 0.0, None)
    rpm = np.where(inA, rA, rB)
    rpm = np.clip(rpm, lim.rpm_lo, lim.rpm_hi)
    if lim.step_max is not None:  # approach each phase's rpm at the rate limit
        prev = np.full(N, np.nan if carry is None or carry.rpm is None else float(carry.rpm))
        s = lim.step_max
        for j in range(K):
            on = minutes[:, j] > 0
            r = rpm[:, j]
            has = on & np.isfinite(prev)
            r = np.where(has, np.clip(r, prev - s, prev + s), r)
            r = np.round(r / lim.rpm_step) * lim.rpm_step
            # onto the dial, a limit that is not a whole number of dial steps (15 rpm on a 10-rpm dial) can
            # round past it by up to half a step: one step back toward the previous rpm
            over = has & (np.abs(r - prev) > s + 1e-9)
            r = np.where(over, r - np.sign(r - prev) * lim.rpm_step, r)
            rpm[:, j] = np.clip(r, lim.rpm_lo, lim.rpm_hi)
            prev = np.where(on, rpm[:, j], np.nan)
    rpm = np.where(minutes > 0, rpm, 0.0)
    return rpm, minutes


def operable(minutes: np.ndarray, grid: Grid, lim: Limits, carry: Carry | None = None):
    """Which schedules keep the dwell limits and the switch budget over the whole horizon.

    Parameters
    ----------
    minutes : ndarray, (N, K)
        Milling minutes per interval (mill first, then rest).
    grid : Grid
    lim : Limits
    carry : Carry, optional
        The state before the first interval; its open period is checked with its logged minutes
        where ``carry.check_open`` (the default), excepted otherwise.

    Returns
    -------
    (ndarray of bool, ndarray of int, ndarray of bool, ndarray of bool)
        Operable, switches used by the batch (with the carried ones), and whether a milling period
        or a rest is at its minimum length (within a minute).
    """
    c = carry or Carry()
    A = np.asarray(minutes, dtype=float)
    N = A.shape[0]
    state = np.full(N, c.state)
    run = np.full(N, float(c.run_min))
    carried = np.full(N, not c.check_open)  # still in the open period, and it is excepted
    sw = np.full(N, int(c.switches))
    bad = np.zeros(N, dtype=bool)
    at_mill = np.zeros(N, dtype=bool)
    at_rest = np.zeros(N, dtype=bool)
    eps = 1e-6
    for j in range(grid.K):
        a, Lk = A[:, j], grid.lengths_min[j]
        mills = a > 0
        start = mills & (state != 1)
        ended_rest = start & (state == 0) & ~carried
        bad |= ended_rest & (run < lim.min_rest - eps)
        at_rest |= ended_rest & (run < lim.min_rest + 1.0 - eps)
        sw += (start & (state != -1)).astype(int)
        run = np.where(start, a, np.where(mills, run + a, run))
        carried &= ~start
        state = np.where(mills, 1, state)
        rest = Lk - a
        has_rest = rest > eps
        stop = has_rest & (state == 1)
        bad |= stop & ~carried & (run < lim.min_mill - eps)
        at_mill |= stop & ~carried & (run < lim.min_mill + 1.0 - eps)
        sw += stop.astype(int)
        carried &= ~stop
        run = np.where(stop, rest, np.where(has_rest, np.where(state == 0, run + rest, rest), run))
        state = np.where(has_rest, 0, state)
    if lim.max_switches is not None:
        bad |= sw > lim.max_switches
    return ~bad, sw, at_mill, at_rest


# --- evaluation --------------------------------------------------------------------------------
@dataclass
class Evaluation:
    """Moment-model prediction of candidate schedules (scenarios x candidates).

    Attributes
    ----------
    x_end : ndarray, (S, N, 6)
        States at the batch end.
    peak_c : ndarray, (S, N)
        Highest vial temperature over the horizon.
    energy_kWh, milling_h : ndarray, (N,)
    nodes : int
        Distinct prefixes integrated (the work done).
    levels : list of (ndarray, ndarray)
        Per interval: states (S, U, 6) at its end and its peak temperature (S, U) of each prefix node.
    node_path : ndarray, (N, K)
        Node of each candidate after each interval (see :meth:`trajectory`).
    """

    x_end: np.ndarray
    peak_c: np.ndarray
    energy_kWh: np.ndarray
    milling_h: np.ndarray
    nodes: int = 0
    levels: list = field(default_factory=list)
    node_path: np.ndarray | None = None
    #: highest vial temperature while milling, (S, N) (-inf: never mills); the ceiling is scored on it
    mill_peak_c: np.ndarray | None = None

    def trajectory(self, i: int, x0s) -> tuple[np.ndarray, np.ndarray]:
        """States (S, K + 1, 6) and interval peaks (S, K) of candidate ``i``."""
        X0 = np.atleast_2d(np.asarray(x0s, dtype=float))
        Xs = [X0] + [lv[0][:, self.node_path[i, j], :] for j, lv in enumerate(self.levels)]
        pk = [lv[1][:, self.node_path[i, j]] for j, lv in enumerate(self.levels)]
        return np.stack(Xs, axis=1), (np.stack(pk, axis=1) if pk else np.zeros((X0.shape[0], 0)))


#: the first minutes of every milling period, integrated with their own substeps: the vial heats fastest
#: there and the rates follow the softening within about a minute (docs/control.md, "Global search")
ONSET_MIN = 5.0


def interval_step(model, X, P, rpm, mill_min, length_min: float, substeps: int | tuple = 2) -> np.ndarray:
    """States after one interval: mill ``mill_min`` minutes at ``rpm``, then rest (eqns (15)-(20)).

    The milling phase is integrated in two parts, its first :data:`ONSET_MIN` minutes and the rest,
    each with ``substeps`` RKC substeps (the stages from the stiffness at the top speed): the start of
    a burst in a cool vial is where the rates change fastest. At 450 rpm in 20-min bursts the final
    mean size is then within 1.5 % of a 32-substep integration, against 9.5 % for three equal
    substeps at the same cost.

    Parameters
    ----------
    model : MomentModel
    X : ndarray, (n, 6)
    P : ndarray, (n, 2) or (n, 3)
        (gamma_mult, delta_mult[, energy_mult]) per row.
    rpm, mill_min : ndarray, (n,)
    length_min : float
        Interval length (min).
    substeps : int or (int, int)
        RKC substeps per part, or (onset part, the rest) (``bmctl design``: (8, 2), a 5-min burst
        integrated as finely as the moment model's own 0.5 h step does it).

    Returns
    -------
    ndarray, (n, 6)
    """
    from ..moments.model import rkc_stages

    c = model.const
    n1, n2 = (substeps, substeps) if np.ndim(substeps) == 0 else substeps
    a = np.minimum(np.asarray(mill_min, dtype=float), length_min)
    a1 = np.minimum(a, ONSET_MIN)
    out = X
    for dur, mill, n in ((a1, a1, max(1, int(n1))), (length_min - a1, a - a1, max(1, int(n2)))):
        top = float(np.max(mill)) if mill.size else 0.0
        dt = np.maximum(dur, 1e-12) / 60.0
        duty = np.where(dur > 1e-12, mill / np.maximum(dur, 1e-12), 0.0)
        st = rkc_stages(c.rate_max_per_h, max(top, 1e-6) / 60.0 / n)
        z = eq.step(eq.NP, c, model.coeffs, [out[:, i] for i in range(6)], [rpm, duty],
                    [P[:, i] for i in range(P.shape[1])], dt, n, st)
        out = np.stack(z, axis=-1)
    return out


def evaluate(model, x0s, ps, rpm: np.ndarray, minutes: np.ndarray, grid: Grid, substeps: int = 2) -> Evaluation:
    """Predict every candidate from every scenario (x0, p) with the moment model's step.

    Parameters
    ----------
    model : MomentModel
    x0s : array_like, (S, 6)
        Start states (one per scenario).
    ps : array_like, (S, 2)
        (gamma_mult, delta_mult) per scenario.
    rpm, minutes : ndarray, (N, K)
        From :func:`expand`.
    grid : Grid
    substeps : int
        RKC substeps per part of the milling phase (:func:`interval_step`).

    Returns
    -------
    Evaluation
    """
    from ..moments.model import rkc_stages

    c, q = model.const, model.coeffs
    X0 = np.atleast_2d(np.asarray(x0s, dtype=float))
    Pp = np.atleast_2d(np.asarray(ps, dtype=float))
    S = X0.shape[0]
    N, K = minutes.shape
    # prefix tree: node id per candidate after each interval
    node = np.zeros(N, dtype=np.int64)
    states = np.repeat(X0[:, None, :], 1, axis=1)  # (S, 1, 6)
    peak = states[:, :, 4].copy()
    energy = np.zeros(1)
    mill_h = np.zeros(1)
    n_nodes = 0
    levels, path = [], np.zeros((N, K), dtype=np.int64)
    for j in range(K):
        key = np.column_stack([node, rpm[:, j], minutes[:, j]])
        uniq, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
        inv = inv.ravel()
        parent = uniq[:, 0].astype(np.int64)
        r_u, a_u = uniq[:, 1], uniq[:, 2]
        U = uniq.shape[0]
        n_nodes += U
        Xp = states[:, parent, :]  # (S, U, 6)
        dt_h = grid.lengths_min[j] / 60.0
        duty = a_u / grid.lengths_min[j]
        w = r_u / c.rpm_max
        T1, _ = eq.thermal_exact(eq.NP, c, Xp[..., 4], Xp[..., 5], w[None, :], a_u[None, :] / 60.0)
        Xn = Xp.copy()
        on = a_u > 0
        if np.any(on):
            idx = np.flatnonzero(on)
            xs = Xp[:, idx, :].reshape(-1, 6)
            pp = np.repeat(Pp, idx.size, axis=0)
            out = interval_step(model, xs, pp, np.tile(r_u[idx], S), np.tile(a_u[idx], S), grid.lengths_min[j],
                                substeps)
            Xn[:, idx, :] = out.reshape(S, idx.size, 6)
        off = ~on
        if np.any(off):
            T2, h2 = eq.thermal_exact(eq.NP, c, Xp[:, off, 4], Xp[:, off, 5], 0.0, dt_h)
            Xn[:, off, 4], Xn[:, off, 5] = T2, h2
        ipk = np.maximum(Xp[..., 4], np.where(on[None, :], T1, Xp[..., 4]))
        peak = np.maximum(peak[:, parent], ipk)
        levels.append((Xn, ipk))
        energy = energy[parent] + c.power_max_W * w ** 3 * (a_u / 60.0) / 1000.0
        mill_h = mill_h[parent] + a_u / 60.0
        states = Xn
        node = inv
        path[:, j] = node
    return Evaluation(states[:, node, :], peak[:, node], energy[node], mill_h[node], n_nodes, levels, path)


def thermal_peaks(model, T0s, h0s, rpm: np.ndarray, minutes: np.ndarray, grid: Grid, power: float = 1.0,
                  per_interval: bool = False, power_first: float | None = None) -> np.ndarray:
    """Highest vial temperature of each schedule from each start (T0, h0): eq. (6) in closed form.

    The vial's temperature and hardening do not depend on the powder's moments, so the ceiling is
    checked for every scenario without integrating the particle field. ``power`` scales the heating
    (the steady-state rise above ambient, :func:`fit_power`); ``per_interval`` returns (S, N, K).

    Parameters
    ----------
    model : MomentModel
    T0s, h0s : array_like, (S,)
        Start temperature (degC) and hardening per scenario.
    rpm, minutes : ndarray, (N, K)
    grid : Grid
    power : float, optional
        Heating factor (1: the card's).
    per_interval : bool, optional
        Return the peak per interval, (S, N, K).
    power_first : float, optional
        Heating factor of the first interval (default ``power``; :attr:`Limits.power_first`).

    Returns
    -------
    ndarray, (S, N)
    """
    c = model.const
    T = np.asarray(T0s, dtype=float)[:, None] * np.ones((1, rpm.shape[0]))
    h = np.asarray(h0s, dtype=float)[:, None] * np.ones((1, rpm.shape[0]))
    peak = T.copy()
    each = []
    w_scale = float(power) ** (1.0 / 3.0)  # P ~ w^3 in eq. (6): the power factor as a speed factor
    w_first = w_scale if power_first is None else float(power_first) ** (1.0 / 3.0)
    for j in range(grid.K):
        w = (rpm[:, j] / c.rpm_max)[None, :]
        ws = w_first if j == 0 else w_scale
        a = (minutes[:, j] / 60.0)[None, :]
        T1, _ = eq.thermal_exact(eq.NP, c, T, h, w * ws, a)
        _, h1 = eq.thermal_exact(eq.NP, c, T, h, w, a)
        pk = np.maximum(T, np.where(a > 0, T1, T))
        peak = np.maximum(peak, pk)
        each.append(pk)
        T, h = eq.thermal_exact(eq.NP, c, T1, h1, 0.0, grid.lengths_min[j] / 60.0 - a)
    return np.stack(each, axis=-1) if per_interval else peak


def _power_normal_equations(model, history, T0: float | None, prior_weight: float) -> tuple[float, float]:
    """(numerator, denominator) of the heating power's least-squares fit (see :func:`fit_power`)."""
    c = model.const
    amb = c.ambient_C
    T = amb if T0 is None else float(T0)
    num, den = prior_weight * 10.0 * 10.0, prior_weight * 10.0 * 10.0  # the prior: f = 1
    for row in history:
        hours, rpm, m = (float(v) for v in row[:3])
        reading = row[3] if len(row) > 3 else None
        a = hours * m if rpm > 0 else 0.0
        b = hours - a
        ea, eb = math.exp(-a / c.cooling_time_h), math.exp(-b / c.cooling_time_h)
        dss = float(eq.power_W(c, rpm / c.rpm_max)) * c.cooling_time_h * 3600.0 / c.heat_capacity_J_per_K
        base = eb * (T - amb) * ea
        d = eb * dss * (1.0 - ea)
        if reading is not None and d > 1e-6:
            y = float(reading) - amb
            num += d * (y - base)
            den += d * d
        T = float(reading) if reading is not None else amb + base + (num / den) * d
    return num, den


def fit_power(model, history, T0: float | None = None, prior_weight: float = 1.0) -> float:
    """The mill's heating power relative to the card's, from logged intervals with vial readings.

    Each interval ``(hours, rpm, milling, reading)`` (mill first, then rest; ``reading`` the vial
    temperature at its end, or None) is predicted from the previous reading by eq. (6) in closed
    form; the end temperature is linear in the power factor f,
    ``T_end - T_amb = e^(-b/tau) [(T_0 - T_amb) e^(-a/tau) + f dT_ss (1 - e^(-a/tau))]``, so f is a
    least-squares fit (with a prior of 1 worth ``prior_weight`` readings of a 10 K rise), clipped to
    [0.5, 2]. Without readings that follow milling, 1.

    Parameters
    ----------
    model : MomentModel
        Supplies the card's thermal constants.
    history : sequence of tuples
        ``(hours, rpm, milling)`` or ``(hours, rpm, milling, reading)``.
    T0 : float, optional
        Vial temperature at the start (default: the card's ambient).
    prior_weight : float

    Examples
    --------
    >>> from bmctl.moments import make_moment_model
    >>> m = make_moment_model("models/alni-1to1-300rpm-lab.toml")
    >>> fit_power(m, [(0.5, 300.0, 1.0)])
    1.0
    """
    num, den = _power_normal_equations(model, history, T0, prior_weight)
    return float(np.clip(num / den, 0.5, 2.0))


def power_bound(model, history, prior_sd: float, z: float, T0: float | None = None,
                prior_weight: float = 1.0) -> tuple[float, float]:
    """The fitted heating power (:func:`fit_power`) and an upper bound at which to check the ceiling.

    The fit is the posterior mean of a linear-Gaussian model: the prior f ~ N(1, prior_sd^2) is
    worth ``prior_weight`` readings of a 10 K rise, so a reading's error has the sd
    ``10 K prior_sd sqrt(prior_weight)`` and the posterior sd is ``prior_sd sqrt(prior_den / den)``.
    Before any reading after milling the bound is ``1 + z prior_sd``; each reading that follows
    a rise of a few tens of kelvin narrows it several-fold. Both are clipped to [0.5, 2].

    Parameters
    ----------
    model : MomentModel
    history : sequence of tuples
        As :func:`fit_power`.
    prior_sd : float
        Relative sd of the mill's heating power against the card's before any reading
        (``[temperature] heating_sd``).
    z : float
        Posterior sds above the fit (``[temperature] heating_z``; 1.645: one-sided 95 %).
    T0, prior_weight
        As :func:`fit_power`.

    Returns
    -------
    (float, float)
        The fitted power and its upper bound.

    Examples
    --------
    >>> from bmctl.moments import make_moment_model
    >>> m = make_moment_model("models/alni-1to1-300rpm-lab.toml")
    >>> f, hi = power_bound(m, [], 0.2, 1.645)
    >>> f, round(hi, 3)
    (1.0, 1.329)
    >>> f, hi = power_bound(m, [(0.5, 300.0, 1.0, 60.0)], 0.2, 1.645)
    >>> bool(hi - f < 0.1)
    True
    """
    num, den = _power_normal_equations(model, history, T0, prior_weight)
    f = num / den
    sd = float(prior_sd) * math.sqrt(prior_weight * 100.0 / den)
    return float(np.clip(f, 0.5, 2.0)), float(np.clip(f + float(z) * sd, 0.5, 2.0))


# --- scoring -----------------------------------------------------------------------------------
def target_errors(X: np.ndarray, target: dict):
    """Signed relative errors per target key of states ``X (..., 6)``: (y - nearest bound) / scale, 0 inside a window.

    Parameters
    ----------
    X : ndarray, (..., 6)
    target : dict
        {key: point or (lo, hi)}.

    Returns
    -------
    ndarray, (..., n_keys)
    """
    keys = list(target)
    Y = output_values(np.asarray(X, dtype=float), keys)
    out = []
    for key, y in zip(keys, Y):
        lo, hi = target_bounds(target[key])
        sc = max(abs(target_centre(target[key])), ERR_FLOOR[key])
        out.append((np.maximum(y - hi, 0.0) + np.minimum(y - lo, 0.0)) / sc)
    return np.stack(out, axis=-1)


@dataclass
class Scores:
    """Per candidate: the nominal scenario's error (root of the summed squared relative errors), the
    RMS of that over all scenarios, the nominal largest error, the ceiling excess (any scenario) and
    the secondary cost."""

    nominal: np.ndarray
    rms: np.ndarray
    error: np.ndarray
    excess_c: np.ndarray
    secondary: np.ndarray


def score(ev: Evaluation, target: dict, lim: Limits, weights, switches: np.ndarray) -> Scores:
    """Scores of evaluated candidates (see :func:`select`).

    Parameters
    ----------
    ev : Evaluation
    target : dict
    lim : Limits
    weights : Weights
        ``energy_per_kWh`` and ``time_per_h`` (the secondary cost), from the controller.
    switches : ndarray, (N,)
    """
    E = target_errors(ev.x_end, target)  # (S, N, k)
    e2 = np.sum(E * E, axis=-1)  # (S, N)
    rms = np.sqrt(np.mean(e2, axis=0))
    err = np.max(np.abs(E[0]), axis=-1) if E.shape[-1] else np.zeros(E.shape[1])
    excess = np.max(ev.peak_c if ev.mill_peak_c is None else ev.mill_peak_c, axis=0) - lim.ceiling_c
    sec = (weights.energy_per_kWh * ev.energy_kWh + weights.time_per_h * ev.milling_h
           + getattr(weights, "switch", 0.0) * switches)
    return Scores(np.sqrt(e2[0]), rms, err, excess, sec)


def select(sc: Scores, band: float, order_key=None) -> int:
    """Index of the best candidate.

    Under the ceiling in every scenario first (else the least excess); then the lowest nominal
    error (the estimate's prediction: the plan steers toward the target); among those within
    ``band`` of it, the lowest error over all scenarios (the filter's spread; in steps of 0.1 %),
    then the lowest secondary cost (energy, milling time, switches), then the lowest index.
    The spread breaks ties only: scored first, a wide posterior would make resting look best
    and the mill would never learn what it is.

    Parameters
    ----------
    sc : Scores
    band : float
        Relative-error band within which candidates count as equally close.
    order_key : ndarray, optional
        Final tie-break (default: the index).
    """
    n = sc.rms.size
    ok = sc.excess_c <= CEILING_TOL_C
    if not np.any(ok):
        ex = np.round(np.maximum(sc.excess_c, 0.0), 2)
        ok = ex <= ex.min() + 1e-12
    best = float(np.min(sc.nominal[ok]))
    pool = np.flatnonzero(ok & (sc.nominal <= best + band + 1e-12))
    tie = np.arange(n) if order_key is None else order_key
    i = np.lexsort((tie[pool], np.round(sc.secondary[pool], 9), np.round(sc.rms[pool], 3)))
    return int(pool[i[0]])


# --- the search --------------------------------------------------------------------------------
@dataclass
class SearchResult:
    """The best operable schedule found and how the search went.

    Attributes
    ----------
    params : ndarray, (9,)
    family : str
    rpm, minutes : ndarray, (K,)
    error : float
        Largest relative target error of the nominal scenario at the batch end.
    rms : float
    peak_c : float
        Highest predicted vial temperature (over the scenarios).
    switches : int
    energy_kWh, milling_h : float
    x_end : ndarray, (6,)
        Nominal end state.
    per_family : dict
        Best row per family: {family: dict(error, peak_c, params, ...)}.
    evaluated : int
        Candidates evaluated (operable ones).
    nodes : int
        Interval integrations done (prefix-tree nodes x scenarios).
    at_min_mill, at_min_rest : bool
    X : ndarray, (S, K + 1, 6)
        Predicted states at the interval ends, per scenario.
    peaks_c : ndarray, (S, K)
        Peak vial temperature per interval, per scenario.
    over_ceiling : dict or None
        The nominally closest candidate that the ceiling ruled out, where it comes at least
        :data:`CLOSER_OVER_CEILING` closer than every candidate under the ceiling (``_summary``
        form), else None.
    """

    params: np.ndarray
    family: str
    rpm: np.ndarray
    minutes: np.ndarray
    error: float
    rms: float
    peak_c: float
    switches: int
    energy_kWh: float
    milling_h: float
    x_end: np.ndarray
    per_family: dict = field(default_factory=dict)
    evaluated: int = 0
    nodes: int = 0
    at_min_mill: bool = False
    at_min_rest: bool = False
    X: np.ndarray | None = None
    peaks_c: np.ndarray | None = None
    over_ceiling: dict | None = None


def _row(rA, MA, jA, kA, rB=0.0, MB=0.0, jB=1.0, cap=NO_CAP, oA=0.0):
    return [rA, MA, jA, kA, oA, rB, MB, jB, cap]


def shift_params(p: np.ndarray, minutes: np.ndarray, s: int) -> np.ndarray:
    """The parameter row of a schedule ``s`` intervals later: the same schedule from then on.

    Parameters
    ----------
    p : ndarray, (9,)
    minutes : ndarray, (K,)
        The schedule's milling minutes (from :func:`expand`), to take the elapsed ones off the cap.
    s : int
        Intervals elapsed.
    """
    q = np.asarray(p, dtype=float).copy()
    q[PARAMS.index("kA")] -= s
    q[PARAMS.index("oA")] += s
    cap = q[PARAMS.index("cap")]
    if cap < NO_CAP:
        q[PARAMS.index("cap")] = max(0.0, cap - float(np.sum(minutes[:s])))
    return q


def coarse_families(grid: Grid, lim: Limits, rpm_step: float) -> tuple[np.ndarray, list[str]]:
    """Parameter rows of the coarse search and their family names.

    Parameters
    ----------
    grid : Grid
    lim : Limits
    rpm_step : float
        Spacing of the coarse rpm grid (a multiple of the dial step).
    """
    K, L, tot = grid.K, grid.interval_min, grid.total_min
    st = max(lim.rpm_step, round(rpm_step / lim.rpm_step) * lim.rpm_step)
    rpms = np.arange(lim.rpm_lo, lim.rpm_hi + 1e-9, st)
    if rpms[-1] < lim.rpm_hi - 1e-9:
        rpms = np.append(rpms, lim.rpm_hi)
    rows, fam = [_row(lim.rpm_lo, 0.0, 1, K, cap=0.0)], ["rest"]
    caps = sorted({float(math.floor(tot * f)) for f in (0.125, 0.25, 0.5, 0.75)} | {NO_CAP})
    for r in rpms:
        for cap in caps:
            if cap >= max(lim.min_mill, 1.0):
                rows.append(_row(r, L, 1, K, cap=cap))
                fam.append("constant")
    cycles = []
    steps = set(CYCLE_STEPS)
    if L < SHORT_STEP_MIN:  # cycles of minutes, not of steps (as on a 30-min grid)
        steps |= {int(round(c / L)) for c in CYCLE_MIN if round(c / L) >= 1}
    for j in sorted(steps):
        if j > K:
            continue
        for duty in (1 / 6, 1 / 4, 1 / 3, 1 / 2, 2 / 3, 3 / 4, 5 / 6):
            M = float(round(duty * j * L))
            if M >= max(lim.min_mill, 1.0) and j * L - M >= max(lim.min_rest, 1.0):
                cycles.append((j, M))
    cycles = sorted(set(cycles))
    for r in rpms:
        for j, M in cycles:
            rows.append(_row(r, M, j, K))
            fam.append("cycled")
    if K >= 2:
        splits = sorted({max(1, min(K - 1, int(round(K * f)))) for f in (0.25, 0.5, 0.75)})
        b_patterns = [(L, 1)] + [(M, j) for j, M in ((2, L), (3, L)) if j * L - M >= lim.min_rest]
        if L < SHORT_STEP_MIN:  # 30 min milling in 1 h and 1.5 h cycles, as on a 30-min grid
            b_patterns += [(SHORT_STEP_MIN, j) for j in sorted({int(round(c / L)) for c in (60.0, 90.0)})
                           if j <= K and j * L - SHORT_STEP_MIN >= max(lim.min_rest, 1.0)
                           and (SHORT_STEP_MIN, j) not in b_patterns]
        offs = (-100.0, -60.0, -30.0, 30.0, 60.0, 100.0)
        for r in rpms:
            for dr in offs:
                rb = r + dr
                if rb < lim.rpm_lo - 1e-9 or rb > lim.rpm_hi + 1e-9:
                    continue
                for kA in splits:
                    for M, j in b_patterns:
                        rows.append(_row(r, L, 1, kA, rb, M, j))
                        fam.append("two-phase")
    return np.array(rows, dtype=float), fam


def _nudge_lengths(grid: Grid, lim: Limits) -> set:
    m = max(float(lim.min_mill), 1.0)
    return {round(v) for v in (m, 2 * m, grid.interval_min) if v <= grid.interval_min + 1e-9}


def nudge_rows(grid: Grid, lim: Limits, rpm_step: float) -> np.ndarray:
    """Parameter rows of single bursts now, then rest: every coarse rpm, for one and two minimum
    milling periods and a whole interval (what ``nudge_above`` of :func:`search` weighs).

    Parameters
    ----------
    grid : Grid
    lim : Limits
    rpm_step : float

    Examples
    --------
    >>> from bmctl.moments import make_moment_model
    >>> from bmctl.control.config import load_controller
    >>> m = make_moment_model("models/alni-1to1-300rpm-lab.toml")
    >>> lim = limits_of(load_controller("controllers/mpc-default.toml"), m)
    >>> rows = nudge_rows(make_grid(0.0, 4.0, 0.5), lim, 100.0)
    >>> sorted({float(c) for c in rows[:, PARAMS.index("cap")]})
    [5.0, 10.0, 30.0]
    """
    st = max(lim.rpm_step, round(rpm_step / lim.rpm_step) * lim.rpm_step)
    rpms = np.unique(np.append(np.arange(lim.rpm_lo, lim.rpm_hi + 1e-9, st), lim.rpm_hi))
    return np.array([_row(r, grid.interval_min, 1, grid.K, cap=float(c))
                     for r in rpms for c in sorted(_nudge_lengths(grid, lim))], dtype=float)


def neighbours(p: np.ndarray, grid: Grid, lim: Limits, minutes_used: float) -> np.ndarray:
    """Parameter rows next to ``p`` on the operable grid: rpm of either phase by one or two dial steps,
    milling minutes per cycle by 1 and 5, cycle length and phase split by one interval, and the
    milling cap by 1 to 60 minutes around the minutes the schedule mills.

    Parameters
    ----------
    p : ndarray, (9,)
    grid : Grid
    lim : Limits
    minutes_used : float
        Total milling minutes of ``p``'s schedule.
    """
    out = []
    st = lim.rpm_step
    L = grid.interval_min

    def add(**kw):
        q = p.copy()
        for k, v in kw.items():
            q[PARAMS.index(k)] = v
        out.append(q)

    rA, MA, jA, kA, oA, rB, MB, jB, cap = p
    for d in (-3, -2, -1, 1, 2, 3):
        add(rA=rA + d * st)
        if kA < grid.K:
            add(rB=rB + d * st)
            add(rA=rA + d * st, rB=rB + d * st)
    for d in (-5, -1, 1, 5):
        if MA < jA * L:
            add(MA=MA + d)
        if kA < grid.K and MB < jB * L:
            add(MB=MB + d)
    for d in (-1, 1):
        if jA + d >= 1 and MA < jA * L:
            add(jA=jA + d, MA=round(MA * (jA + d) / jA), oA=0.0)
        if 1 <= kA + d <= grid.K:
            add(kA=kA + d)
    base = min(cap, minutes_used)
    for d in (-60, -30, -10, -3, -1, 1, 3, 10, 30, 60):
        add(cap=max(0.0, base + d))
    add(cap=NO_CAP)
    return np.array(out, dtype=float)


def _fine_rows(Pc: np.ndarray, f: int) -> np.ndarray:
    """Parameter rows of a grid ``f`` times coarser, on the fine grid (the same schedules)."""
    P = np.array(Pc, dtype=float)
    for name in ("jA", "kA", "oA", "jB"):
        P[:, PARAMS.index(name)] *= f
    return P


def search(model, x0s, ps, target: dict, grid: Grid, lim: Limits, weights, carry: Carry | None = None,
           substeps: int = 2, rpm_step: float = 20.0, band: float = 0.002, rounds: int = 1, keep: int = 6,
           extra=None, coarse: bool = True, coarse_factor: int = 2, pool: int = 8, pool_band: float = 0.03,
           risk: float = 0.25, give_up_above: float | None = None,
           rest_within: float | None = None, nudge_above: float | None = None) -> SearchResult | None:
    """Coarse batch over the families, then rounds of neighbours of the best few (and of the best per
    family), every candidate operable over the whole horizon; the best within the error band are then
    scored on the spread.

    Parameters
    ----------
    model : MomentModel
    x0s, ps : array_like, (S, 6) and (S, 2)
        The nominal start state and (gamma_mult, delta_mult) first, then the spread (e.g. a weighted
        selection of the filter's particles, or its quantile corners).
    target : dict
    grid : Grid
    lim : Limits
    weights : Weights
    carry : Carry, optional
    substeps : int
    rpm_step : float
        Coarse rpm spacing.
    band : float
        Error band of :func:`select`.
    rounds : int
        Local-search rounds on the grid (each stops early when nothing improved).
    keep : int
        Rows whose neighbours each round evaluates (besides the best of each family).
    extra : list of (ndarray, str), optional
        Further parameter rows (e.g. the previous plan's) with their family names.
    coarse : bool
        Include the coarse families (False: only ``extra`` and their neighbours).
    coarse_factor : int
        The coarse batch runs on a grid this many intervals per step (cycles of whole multiples);
        its best rows are carried to the interval grid, where every score is recomputed.
    pool : int
        Size of the pool scored on the spread: the nominally closest half and the cheapest quarter within
        ``pool_band`` of the nominal best, and the cheapest of each family there (so resting on, when it
        is that close, is weighed against a plan whose outcome the spread scatters; further off, the
        mill is not left idle while the filter still has to learn what it is).
    pool_band : float
        Relative-error band of the pool.
    risk : float
        Weight of the variance the plan adds over the spread in the pool's score
        ``e_nominal^2 + risk (Var(e) - Var_rest(e)) +`` a small share of the secondary cost
        (:data:`RISK_COST`). ``Var_rest`` is the spread of resting on (the state's own uncertainty,
        common to every plan and narrowed by the next samples); 1 would weigh the added variance as
        in the expected squared error of the plan run open loop; less counts on the feedback that
        later plans give (docs/control.md).
    give_up_above : float, optional
        Return None, before the spread is scored, when no candidate comes within this error of the
        target (the caller would reject the result: a local search that then gives way to a global one).
    rest_within : float, optional
        Resting on (no milling to the batch end) enters the spread-scored pool only when its own
        predicted error is within this, or when no plan that mills is in the pool. The planner
        passes its ``[objective] tolerance`` while the mill has not milled yet in the batch.
    nudge_above : float, optional
        When resting on is predicted further than this (relative error) from the target, single
        bursts now, then rest (:func:`nudge_rows`: every coarse rpm, one and two minimum milling
        periods and a whole interval) are evaluated too, and the nominally closest of each length
        that comes closer than resting joins the spread-scored pool: a small step toward the target
        whose outcome the spread scatters little, weighed against resting on and against the closer
        but wider plans. ``None``: off (the planner passes ``[objective] tolerance`` when
        ``[plan] nudge`` is set).

    Examples
    --------
    >>> import numpy as np
    >>> from bmctl.moments import make_moment_model
    >>> from bmctl.control.config import load_controller
    >>> m = make_moment_model("models/alni-1to1-300rpm-lab.toml")
    >>> cfg = load_controller("controllers/mpc-default.toml")
    >>> g, lim = make_grid(0.0, 2.0, 0.5), limits_of(cfg, m)
    >>> r = search(m, m.x0()[None], np.ones((1, 2)), {"s_mean_um": 60.0}, g, lim, cfg.weights)
    >>> bool(r.error < 0.02 and r.peak_c <= lim.ceiling_c)
    True
    """
    carry = carry or Carry()
    x0s = np.atleast_2d(np.asarray(x0s, dtype=float))
    ps = np.atleast_2d(np.asarray(ps, dtype=float))
    C: dict[str, list] = {k: [] for k in ("P", "F", "rpm", "min", "sw", "atm", "atr", "nom", "rms", "err", "exc",
                                          "sec", "x_end", "peak", "E", "mh", "run", "idx", "defer")}
    runs: list[Evaluation] = []
    seen: set = set()
    work = {"nodes": 0, "coarse": 0}

    def evaluate_rows(P, F, g, store: bool):
        rpm, mins = expand(P, g, lim, carry)
        ok, sw, at_m, at_r = operable(mins, g, lim, carry)
        take, keys = [], set()
        for i in np.flatnonzero(ok):
            kb = rpm[i].tobytes() + mins[i].tobytes()
            if (not store or kb not in seen) and kb not in keys:
                keys.add(kb)
                take.append(i)
        if not take:
            return None
        idx = np.array(take)
        ev = evaluate(model, x0s[:1], ps[:1], rpm[idx], mins[idx], g, substeps)
        # the ceiling in every scenario, eq. (6) in closed form with the mill's fitted heating power
        # (one pass, per interval). The ceiling is a limit on milling: it is scored on the intervals
        # that mill, so a vial already above it (a hot start, or a hot filter particle) makes every
        # milling candidate exceed it while a rest does not; scored on the start temperature too,
        # every candidate would tie and the closest would mill on.
        each = thermal_peaks(model, x0s[:, 4], x0s[:, 5], rpm[idx], mins[idx], g, lim.power, per_interval=True,
                             power_first=lim.power_first)
        ev.peak_c = np.maximum(x0s[:, 4][:, None], each.max(axis=-1, initial=-np.inf))
        ev.mill_peak_c = np.where(mins[idx][None] > 0, each, -np.inf).max(axis=-1, initial=-np.inf)
        work["nodes"] += ev.nodes
        sc = score(ev, target, lim, weights, sw[idx])
        defer = (mins[idx, 0] <= 0) & (mins[idx, 1:].sum(axis=1) > 0) if g.K > 1 else np.zeros(idx.size, bool)
        defer &= not carry.rests_on(lim)  # (milling now is not open to any plan)
        sc.nominal = sc.nominal + DEFER_PENALTY * defer  # milling later what could be milled now: ranks lower
        if not store:
            return idx, sc
        seen.update(keys)
        runs.append(ev)
        for key, vals in (("P", P[idx]), ("F", [F[i] for i in idx]), ("rpm", rpm[idx]), ("min", mins[idx]),
                          ("sw", sw[idx]), ("atm", at_m[idx]), ("atr", at_r[idx]), ("nom", sc.nominal),
                          ("rms", sc.rms), ("err", sc.error), ("exc", sc.excess_c), ("sec", sc.secondary),
                          ("x_end", ev.x_end[0]), ("peak", np.max(ev.peak_c, axis=0)), ("E", ev.energy_kWh),
                          ("defer", defer),
                          ("mh", ev.milling_h)):
            C[key] += list(vals)
        C["run"] += [len(runs) - 1] * idx.size
        C["idx"] += list(range(idx.size))
        return idx, sc

    def scores(ids=None) -> Scores:
        ids = range(len(C["rms"])) if ids is None else ids
        return Scores(*(np.array([C[k][i] for i in ids], dtype=float) for k in ("nom", "rms", "err", "exc", "sec")))

    def best_of(ids) -> int:
        return ids[select(scores(ids), band)]

    def heads_of(sc: Scores, fams, n_keep) -> list[int]:
        ok = sc.excess_c <= CEILING_TOL_C
        order = np.lexsort((np.arange(sc.rms.size), sc.secondary, np.where(ok, sc.nominal, np.inf)))
        heads = [int(h) for h in order[:n_keep]]
        for f in FAMILIES:  # the best of each family too
            ids = [i for i, ff in enumerate(fams) if ff == f]
            if ids:
                sub = Scores(sc.nominal[ids], sc.rms[ids], sc.error[ids], sc.excess_c[ids], sc.secondary[ids])
                heads.append(ids[select(sub, band)])
        return list(dict.fromkeys(heads))

    def with_neighbours(rows, fams):
        out, fo = [rows], list(fams)
        for r, f in zip(rows, fams):
            nb = neighbours(r, grid, lim, float(np.sum(expand(r[None], grid, lim, carry)[1])))
            out.append(nb)
            fo += [f] * nb.shape[0]
        return np.vstack(out), fo

    start_rows, start_fams = np.zeros((0, len(PARAMS))), []
    if coarse:
        f = int(coarse_factor)
        cg = make_grid(grid.t0_h, grid.t0_h + grid.total_min / 60.0, grid.interval_min * f / 60.0) if f > 1 else None
        if cg is not None and cg.K >= 4:
            Pc, fc = coarse_families(cg, lim, rpm_step)
            got = evaluate_rows(Pc, fc, cg, store=False)
            work["coarse"] = 0 if got is None else got[0].size
            if got is not None:
                idx, sc = got
                fams = [fc[i] for i in idx]
                hs = heads_of(sc, fams, keep)
                start_rows = _fine_rows(Pc[idx[hs]], f)
                start_fams = [fams[h] for h in hs]
                start_rows, start_fams = with_neighbours(start_rows, start_fams)
        else:
            start_rows, start_fams = coarse_families(grid, lim, rpm_step)
    if extra:
        ex = np.vstack([np.atleast_2d(e[0]) for e in extra])
        exf = [e[1] for e in extra]
        ex, exf = with_neighbours(ex, exf)
        start_rows = np.vstack([start_rows, ex])
        start_fams = start_fams + exf
    start_rows = np.vstack([start_rows, [_row(lim.rpm_lo, 0.0, 1, grid.K, cap=0.0)]])
    start_fams = start_fams + ["rest"]
    evaluate_rows(start_rows, start_fams, grid, store=True)
    if not C["rms"]:  # nothing operable (e.g. the switch budget is spent while milling): rest anyway
        raise RuntimeError("no operable schedule, not even a rest")
    best = best_of(list(range(len(C["rms"]))))
    for _ in range(max(0, rounds)):
        hs = heads_of(scores(), C["F"], keep)
        nbs = [neighbours(C["P"][h], grid, lim, float(np.sum(C["min"][h]))) for h in hs]
        fams = [C["F"][h] for h, nb in zip(hs, nbs) for _ in range(nb.shape[0])]
        if evaluate_rows(np.vstack(nbs), fams, grid, store=True) is None:
            break
        new_best = best_of(list(range(len(C["rms"]))))
        if new_best == best:
            break
        best = new_best
    if give_up_above is not None and float(np.min(C["err"])) > give_up_above:
        return None  # the result's error (that of one of the candidates) would exceed it too
    nudges: list[int] = []
    if nudge_above is not None and x0s.shape[0] > 1:
        still = [i for i in range(len(C["rms"])) if C["mh"][i] <= 0.0 and not C["defer"][i]]
        e_rest = min((C["nom"][i] for i in still), default=0.0)
        if e_rest > nudge_above:
            Pn = nudge_rows(grid, lim, rpm_step)
            evaluate_rows(Pn, ["constant"] * Pn.shape[0], grid, store=True)  # (those already evaluated: skipped)
            lengths, best_of_length = _nudge_lengths(grid, lim), {}
            for i in range(len(C["rms"])):  # the nominally closest burst of each length that beats resting
                m = round(float(np.sum(C["min"][i])))
                if (C["F"][i] == "constant" and C["mh"][i] > 0.0 and C["exc"][i] <= CEILING_TOL_C
                        and C["nom"][i] < e_rest - 1e-9 and m in lengths):
                    j = best_of_length.get(m)
                    if j is None or round(C["nom"][i], 9) < round(C["nom"][j], 9):
                        best_of_length[m] = i
            nudges = [best_of_length[m] for m in sorted(best_of_length)]
    Xs = None
    if x0s.shape[0] > 1:  # the spread: a pool of the nominally closest plans, scored on every particle
        sc = scores()
        ok = sc.excess_c <= CEILING_TOL_C
        if not np.any(ok):
            ex = np.round(np.maximum(sc.excess_c, 0.0), 2)
            ok = ex <= ex.min() + 1e-12
        bnom = float(np.min(sc.nominal[ok]))
        near = np.flatnonzero(ok & (sc.nominal <= bnom + max(band, pool_band) + 1e-12))
        if rest_within is not None:
            idle = np.array([C["mh"][i] <= 0.0 and C["err"][i] > rest_within for i in near], dtype=bool)
            if np.any(idle) and not np.all(idle):
                near = near[~idle]
        by_nom = near[np.lexsort((near, np.round(sc.secondary[near], 9), np.round(sc.nominal[near], 4)))]
        by_cost = near[np.lexsort((near, np.round(sc.nominal[near], 4), np.round(sc.secondary[near], 9)))]
        cand = list(by_nom[:max(1, int(pool) // 2)]) + list(by_cost[:max(1, int(pool) // 4)])
        for f in FAMILIES:  # the cheapest of each family within the pool band (resting on, when that is close)
            ids = [i for i in by_cost if C["F"][i] == f]
            if ids:
                cand.append(ids[0])
        in_band = set(near.tolist())
        cand += [i for i in nudges if i in in_band]  # small steps toward the target (nudge_above)
        cand = np.array(sorted(dict.fromkeys(int(i) for i in cand)))
        R = np.array([C["rpm"][i] for i in cand])
        A = np.array([C["min"][i] for i in cand])
        ev = evaluate(model, x0s[1:], ps[1:], R, A, grid, substeps)
        work["nodes"] += ev.nodes * (x0s.shape[0] - 1)
        E0 = target_errors(np.array([C["x_end"][i] for i in cand]), target)  # (n, k)
        E1 = target_errors(ev.x_end, target)  # (S - 1, n, k)
        var = np.mean(np.sum((E1 - E1.mean(axis=0)) ** 2, axis=-1), axis=0)
        # the spread the plan adds: what the state's own uncertainty gives a rest is common to every plan
        Er = target_errors(x0s[1:], target)
        var = np.maximum(var - np.mean(np.sum((Er - Er.mean(axis=0)) ** 2, axis=-1)), 0.0)
        e_nom = np.sqrt(np.sum(E0 * E0, axis=-1)) + DEFER_PENALTY * np.array([C["defer"][i] for i in cand])
        J = e_nom * e_nom + risk * var + RISK_COST * sc.secondary[cand]
        rms = np.sqrt(np.mean(np.sum(E1 * E1, axis=-1), axis=0))
        for n, i in enumerate(cand):
            C["rms"][i] = float(rms[n])
        k = int(np.lexsort((cand, np.round(J, 9)))[0])
        best = int(cand[k])
        Xs, _ = ev.trajectory(k, x0s[1:])
    else:
        best = best_of(list(range(len(C["rms"]))))
    per_family = {}
    for f in FAMILIES:
        ids = [i for i, ff in enumerate(C["F"]) if ff == f]
        if ids:
            per_family[f] = _summary(C, best_of(ids) if f != C["F"][best] else best, grid)
    # closer than every schedule under the ceiling (not only the plan: the spread may choose a plan
    # other than the nominally closest, and then the ceiling is not what keeps it)
    under = [C["err"][i] for i in range(len(C["err"])) if C["exc"][i] <= CEILING_TOL_C]
    closest_under = min(under) if under else np.inf
    over = [i for i in range(len(C["err"]))
            if C["exc"][i] > CEILING_TOL_C and C["err"][i] < closest_under - CLOSER_OVER_CEILING]
    over_ceiling = (_summary(C, min(over, key=lambda i: (C["err"][i], i)), grid)
                    if over and C["exc"][best] <= CEILING_TOL_C else None)
    X, pk = runs[C["run"][best]].trajectory(C["idx"][best], x0s[:1])
    if Xs is not None:
        X = np.concatenate([X, Xs], axis=0)
    return SearchResult(np.asarray(C["P"][best]), str(C["F"][best]), np.asarray(C["rpm"][best]),
                        np.asarray(C["min"][best]), float(C["err"][best]), float(C["rms"][best]),
                        float(C["peak"][best]), int(C["sw"][best]), float(C["E"][best]), float(C["mh"][best]),
                        X[0, -1].copy(), per_family, len(C["rms"]) + work["coarse"], int(work["nodes"]),
                        bool(C["atm"][best]), bool(C["atr"][best]), X, pk, over_ceiling)


def _summary(C: dict, i: int, grid: Grid) -> dict:
    rpm, mins = C["rpm"][i], C["min"][i]
    on = mins > 0
    return {"family": str(C["F"][i]), "error": float(C["err"][i]), "rms": float(C["rms"][i]),
            "peak_c": float(C["peak"][i]), "energy_kWh": float(C["E"][i]), "milling_h": float(C["mh"][i]),
            "switches": int(C["sw"][i]), "schedule": describe(rpm, mins, grid),
            "params": [float(v) for v in C["P"][i]]}


#: the most rpm phases :func:`describe` names in order (more: their range and count)
DESCRIBED_PHASES = 3


def describe(rpm: np.ndarray, minutes: np.ndarray, grid: Grid) -> str:
    """A short text of a schedule: its rpm phases in time order, the hours milled and in how many
    intervals, e.g. "140 then 100 rpm, 6.00 h milling in 12 of 24 intervals (continuous)".

    Up to :data:`DESCRIBED_PHASES` phases (runs of one rpm among the milled intervals) are named in
    order; more are given as their range and count.

    Parameters
    ----------
    rpm, minutes : ndarray, (K,)
        The rpm and the minutes milled in each interval of ``grid``.
    grid : Grid

    Returns
    -------
    str

    Examples
    --------
    >>> g = make_grid(0.0, 4.0, 0.5)
    >>> describe(np.r_[[140.0] * 4, [100.0] * 4], np.r_[[30.0] * 4, [30.0] * 4], g)
    '140 then 100 rpm, 4.00 h milling in 8 of 8 intervals (continuous)'
    >>> describe(np.full(8, 450.0), np.r_[[10.0, 0.0] * 4], g)
    '450 rpm, 0.67 h milling in 4 of 8 intervals'
    >>> describe(np.zeros(8), np.zeros(8), g)
    'rest'
    """
    on = minutes > 0
    if not on.any():
        return "rest"
    milled = [int(r) for r in rpm[on]]
    phases = [r for k, r in enumerate(milled) if k == 0 or r != milled[k - 1]]
    if len(phases) <= DESCRIBED_PHASES:
        rtxt = " then ".join(str(r) for r in phases) + " rpm"
    else:
        rtxt = f"{min(phases)}-{max(phases)} rpm in {len(phases)} phases"
    full = np.all(minutes[on] >= grid.lengths_min[on] - 1e-9)
    return f"{rtxt}, {minutes.sum() / 60:.2f} h milling in {int(on.sum())} of {grid.K} intervals" + \
        (" (continuous)" if full and np.all(np.diff(np.flatnonzero(on)) == 1) else "")
