"""What ``advise`` reports, as pure helpers of a campaign: the measured sample, the planned
schedule to the batch end, the predicted end-state band and why (reachability, binding constraints)."""

from __future__ import annotations

import math
import os
import re
from pathlib import Path

import numpy as np

from ..errors import InputError
from .band import propagate

EPS_H = 1e-9
#: filter particles propagated to the batch end for the predicted end-state band
BAND_PARTICLES = 64
#: relative error of the predicted end median within which a target counts as reached
REACH_TOL = 0.03
#: two-sided 95 % quantile of the normal law: the sample-size hint reads the mean size to +-tolerance at 95 %
Z95 = 1.959963984540054
#: an advice asks for another sample only while fewer than this many were taken at its batch time
SAMPLES_PER_TIME_MAX = 2


def _band_indices(w: np.ndarray, n: int) -> np.ndarray:
    """Deterministic systematic selection of ``n`` particles by weight (no random draw)."""
    c = np.cumsum(w / w.sum())
    return np.minimum(np.searchsorted(c, (np.arange(n) + 0.5) / n), w.size - 1)


def _measure(inputs, um_per_px, accept_unusable: bool = False, scale_name: str = "um_per_px",
             accept_name: str = "accept_unusable=True", scale_bar_um: float | None = None):
    """Pooled particle table, each particle's image, its position, per-input reports of images and
    tables (as ``bmctl measure``) and each input's particle count (in the order of ``inputs``).

    An image (or a table's image, by its ``measure.json``) with the verdict ``unusable`` is
    refused unless ``accept_unusable``; doubtful ones are listed in the reports' ``verdict_warnings``.
    The messages name ``um_per_px`` as ``scale_name`` and the way to accept an unusable image as
    ``accept_name`` (:func:`bmctl.campaign.workflow.arg`). ``scale_bar_um``: the length on the
    images' scale bar, as ``bmctl measure --scale-bar-um``.
    """
    from ..measure.micrograph import check_verdicts, measure_micrograph, table_reports
    from ..measure.scale import check_scale
    from ..measure.tables import ParticleTable, check_table, read_table_with_locations

    scale = check_scale(um_per_px, scale_name) if um_per_px is not None else None
    tables, images, xs, ys, reports, counts = [], [], [], [], [], []
    for i, item in enumerate(inputs):
        if isinstance(item, ParticleTable):  # a table given by its columns: checked as a file's rows are
            t, name = check_table(item, f"inputs[{i}] (a table)"), "(table)"
            x = y = np.full(len(t), np.nan)
            reports.append({"table": name, "count": len(t)})
        elif Path(item).suffix.lower() == ".csv":
            (t, where), name = read_table_with_locations(item), str(item)  # where: a table `bmctl measure` wrote
            x = y = np.full(len(t), np.nan)  # (each particle's image and centroid), else None
            side = table_reports(item)
            reports.append({"table": name, "count": len(t),
                            "verdict_warnings": check_verdicts(side, accept_unusable, accept_name)})
            if where is not None:
                name, x, y = where
        else:
            res = measure_micrograph(item, um_per_px=scale, scale_bar_um=scale_bar_um)
            t, name, x, y = res.table, str(item), res.x_um, res.y_um
            rep = res.report()
            rep["verdict_warnings"] = check_verdicts([rep], accept_unusable, accept_name)
            reports.append(rep)
        tables.append(t)
        counts.append(len(t))
        images += [name] * len(t) if isinstance(name, str) else list(name)
        xs.append(np.asarray(x, float))
        ys.append(np.asarray(y, float))
    table = ParticleTable.concat(tables)
    if len(table) == 0:
        first = inputs[0] if isinstance(inputs[0], (str, os.PathLike)) else "inputs[0] (a table)"
        raise InputError(f"{first}: no particles found (check the scale or the table)")
    return table, images, np.concatenate(xs), np.concatenate(ys), reports, counts


def _schedule(c, plan, t_h: float) -> list[dict]:
    """The plan's applied inputs from ``t_h`` to the batch end (beyond the horizon: its last input held)."""
    H = c.meta["hours"]
    dt = plan.interval_h
    U = plan.applied()
    if U.shape[0]:
        U[0] = plan.u_apply
    rows, t, k = [], t_h, 0
    while t < H - EPS_H:
        rpm, m = (float(v) for v in (U[min(k, U.shape[0] - 1)] if U.shape[0] else (0.0, 0.0)))
        h = min(dt, H - t)
        mill_min = round(m * dt * 60.0)
        mill_min = min(mill_min, round(h * 60.0))
        rows.append({"t0_h": t, "t1_h": t + h, "rpm": rpm if mill_min > 0 else 0.0, "milling": mill_min / (h * 60.0),
                     "mill_min": mill_min, "rest_min": round(h * 60.0) - mill_min, "planned": k < U.shape[0]})
        t += h
        k += 1
    return rows


def _vial_through(model, T, h, sched: list[dict]):
    """Vial temperature and hardening after the schedule's rows from (T, h): eq. (6) in closed form."""
    from ..moments import equations as eq

    c = model.const
    for row in sched:
        dt = row["t1_h"] - row["t0_h"]
        a = float(row["milling"]) * dt if row["rpm"] > 0 else 0.0
        T, h = eq.thermal_exact(eq.NP, c, T, h, float(row["rpm"]) / c.rpm_max, a)
        T, h = eq.thermal_exact(eq.NP, c, T, h, 0.0, dt - a)
    return T, h


def _end_band(c, sched: list[dict], plan=None) -> dict:
    """Median and 90 % band of the moments at the batch end: filter particles (a deterministic
    weighted selection) propagated by the moment model under the schedule, each vial at its
    own heating gain over the card's thermal law (as the filter propagates them); D50 read out
    as the estimate's (:func:`bmctl.moments.model.size_stats_of_state`). A plan made on operable
    schedules has already predicted its spread particles (the same selection): their moments are
    used, and only the vial temperatures are run through the schedule (closed form)."""
    from ..moments.model import size_stats_of_state

    lp = c.loop
    pf = lp.estimator
    idx = _band_indices(pf.weights, BAND_PARTICLES)
    X0 = pf.X[idx].copy()
    gain, amb = pf.gain[idx], pf.ambient_c
    X0[:, 4] = amb + (X0[:, 4] - amb) / gain
    Xs = None if plan is None else plan.extra.get("spread_x_end")
    if Xs is not None and len(Xs) == len(idx):
        X = np.array(Xs, dtype=float)
        X[:, 4], X[:, 5] = _vial_through(lp.model, X0[:, 4], X0[:, 5], sched)
    else:
        X = propagate(lp.model, X0, pf.P[idx], sched)
    X[:, 4] = amb + gain * (X[:, 4] - amb)
    out = {}
    names = ("s_mean_um", "s_std_um", "r_mean", "r_std", "temperature_c")
    vals = {k: X[:, i] for i, k in enumerate(names)}
    vals["d50_um"] = size_stats_of_state(X)["d50_um"]
    for k, v in vals.items():
        q = np.quantile(v, [0.05, 0.5, 0.95])
        out[k] = {"median": float(q[1]), "q05": float(q[0]), "q95": float(q[2])}
    return out


def _why(c, plan, sched, end, ctrl_target) -> tuple[dict, list[str]]:
    """Per target: reachable by the batch end?  And which constraints bind in the plan."""
    reach = {}
    for k, v in c.meta["target"].items():
        e = end.get(k)
        if e is None:
            continue
        inside = e["q05"] <= v <= e["q95"]
        reach[k] = bool(inside or abs(e["median"] - v) <= REACH_TOL * abs(v))
    binding = []
    cfg = c.loop.controller.cfg
    if getattr(cfg, "kind", "") == "recipe":
        return reach, ["open-loop recipe: the schedule is fixed, no constraint is weighed"]
    if "binding" in plan.extra:  # a plan on operable schedules names the limits it runs against itself
        binding = list(plan.extra["binding"])
        if not all(reach.values()) and not binding:
            binding.append("none of the mill's limits: the model cannot reach the target from this estimate")
        return reach, binding
    # the planned rows as the schedule shows them (whole minutes): a milling share the mill's limits
    # round to a rest binds nothing ("rpm at its upper bound" beside "next: 0 rpm")
    rows = [r for r in sched if r.get("planned", True)]
    U = np.array([[r["rpm"], r["milling"]] for r in rows], dtype=float).reshape(-1, 2)
    on = np.array([r["mill_min"] > 0 for r in rows], dtype=bool)
    b = getattr(cfg, "bounds", None)
    if b is not None and on.any():
        hi = min(b.rpm_max, c.loop.model.rpm_max)
        if np.any(U[on, 0] >= hi - 1.0):
            binding.append(f"rpm at its upper bound ({hi:g} rpm)")
        if np.any(U[on, 0] <= b.rpm_min + 1.0):
            binding.append(f"rpm at its lower bound ({b.rpm_min:g} rpm)")
        both = on[1:] & on[:-1]  # consecutive milling intervals
        if b.rpm_step_max is not None and np.any(np.abs(np.diff(U[:, 0]))[both] >= b.rpm_step_max - 1.0):
            binding.append(f"rpm rate limit ({b.rpm_step_max:g} rpm per interval)")
        if np.all(U[on, 1] >= b.milling_max - 1e-3) and on.all():
            binding.append(f"milling share at its maximum ({b.milling_max:g}) throughout")
    if hasattr(cfg, "temperature") and plan.t_peak_c.size:
        ceil = plan.status.t_ceiling_c if math.isfinite(plan.status.t_ceiling_c) else cfg.temperature.ceiling_c
        if float(np.max(plan.t_peak_c)) >= ceil - 0.5:
            binding.append(f"vial-temperature ceiling ({ceil:g} °C)")
    binding += mill_limits_binding(getattr(plan.status, "reason", ""), getattr(cfg, "mill", None),
                                   60.0 * plan.interval_h if hasattr(plan, "interval_h") else None)
    if not all(reach.values()) and not binding:
        binding.append("batch time: the target is not reached by the batch end at the planned inputs")
    return reach, binding


_DWELL_NOTE = re.compile(r"^dwell(?: limits)?: milling ([0-9.]+) -> ([0-9.]+) min")
_SWITCH_NOTE = re.compile(r"^switch budget \((\d+)\) spent: milling ([0-9.]+) -> ([0-9.]+)")


def mill_limits_binding(reason: str, mill=None, interval_min: float | None = None) -> list[str]:
    """The mill's limits that changed the advised interval, read from the controller's status reason
    (the notes of :meth:`bmctl.control.mill.MillGuard.enforce` and of the MPC's dwell re-solve), in
    the words of :func:`bmctl.control.planner.plan_binding`; ``mill``: the controller's ``[mill]``,
    ``interval_min``: the control interval (min) the notes' minutes are of.

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> mill = SimpleNamespace(min_mill_min=5.0, min_rest_min=5.0)
    >>> mill_limits_binding("dwell limits: milling 3 -> 0 min", mill)
    ['minimum milling period (5 min) now: the 3 min of milling planned round to a rest']
    >>> mill_limits_binding("temperature guard: milling 1.00 -> 0.90; dwell limits: milling 27 -> 30 min", mill, 30)
    ['minimum rest (5 min) now: the milling planned rounds from 27 to 30 min']
    >>> mill_limits_binding("dwell: milling 3.4 -> 5 min (re-solved)", mill)
    ['minimum milling period (5 min) now: the 3.4 min of milling planned round up to 5 min']
    >>> mill_limits_binding("switch budget (36) spent: milling 0.50 -> 0.00", mill)
    ['switch budget (36 switches) spent now: milling share 0.5 -> 0']
    >>> mill_limits_binding("dlqr, 1 it", mill)
    []
    """
    out = []
    lo_mill = float(getattr(mill, "min_mill_min", 0.0) or 0.0)
    lo_rest = float(getattr(mill, "min_rest_min", 0.0) or 0.0)
    for part in (reason or "").split("; "):
        m = _DWELL_NOTE.match(part.strip())
        if m:
            a, b = float(m.group(1)), float(m.group(2))
            if lo_mill and 0 < a < lo_mill:
                out.append(f"minimum milling period ({lo_mill:g} min) now: the {a:g} min of milling planned round "
                           + ("to a rest" if b == 0 else f"up to {b:g} min"))
            elif lo_rest and b > 0 and (b > a if interval_min is None else 0 < interval_min - a < lo_rest):
                out.append(f"minimum rest ({lo_rest:g} min) now: the milling planned rounds from {a:g} to {b:g} min")
            else:
                out.append(f"the mill's dwell limits (milling at least {lo_mill:g} min, rests at least {lo_rest:g} "
                           f"min) now: the milling planned rounds from {a:g} to {b:g} min")
            continue
        m = _SWITCH_NOTE.match(part.strip())
        if m:
            out.append(f"switch budget ({m.group(1)} switches) spent now: milling share {float(m.group(2)):g} -> "
                       f"{float(m.group(3)):g}")
    return out


def cooling_now(binding) -> bool:
    """Whether the plan rests to the batch end because the vial is at the ceiling now (``binding``
    as :func:`bmctl.control.planner.plan_binding` words it): reachability is judged by the next
    advice, when a plan may mill again.

    >>> cooling_now(["vial-temperature ceiling (80 °C) now: the vial is at it (...); ... plans milling again"])
    True
    >>> cooling_now(["vial-temperature ceiling (80 °C) now: ... with 3 of 3 switches used the mill cannot start again "
    ...              "this batch"])   # the budget spent: the resting plan's verdict is the batch's
    False
    >>> cooling_now(["vial-temperature ceiling (80 °C) from 2 h"])
    False
    """
    return any(isinstance(b, str) and b.startswith("vial-temperature ceiling (") and ") now:" in b
               and b.endswith("plans milling again") for b in binding or [])


def reach_line(key: str, target: float, end: dict | None, reachable: bool, cooling: bool = False) -> str:
    """The ``why`` line of one target: reached by the predicted median, only inside the 90 % band,
    or not at all, with the numbers that say which.

    A target inside the band but away from the median is reachable only if the mill is not what the
    estimate says: the advice does not call that plainly "reachable" (the band at the first advice
    is the card's wide prior and holds nearly every target).

    Parameters
    ----------
    key : str
        The target's quantity (e.g. ``s_mean_um``).
    target : float
        The target value.
    end : dict or None
        The predicted batch end of ``key``: ``median``, ``q05``, ``q95`` (``advise``'s ``end``).
    reachable : bool
        ``advise``'s ``reachable`` for the target.
    cooling : bool, optional
        The plan rests to the batch end because the vial is at the ceiling now
        (:func:`cooling_now`): an unreachable verdict is the resting plan's, not the target's.

    Examples
    --------
    >>> reach_line("s_mean_um", 30.0, {"median": 30.4, "q05": 27.0, "q95": 35.0}, True)
    'target s_mean_um = 30 is reachable by the batch end (predicted median 30.4)'
    >>> import textwrap
    >>> print(textwrap.fill(reach_line("s_mean_um", 30.0, {"median": 34.93, "q05": 23.57, "q95": 72.33}, True), 100))
    target s_mean_um = 30 lies inside the 90 % band of the batch end [23.57, 72.33], but the predicted
    median misses it (34.93, +16.4 %): reachable only if the mill is not what the estimate says; samples
    narrow the band
    >>> reach_line("s_mean_um", 400.0, {"median": 41.1, "q05": 39.0, "q95": 44.0}, False)
    'target s_mean_um = 400 is NOT reachable by the batch end (predicted median 41.1, 90 % band [39, 44])'
    >>> print(textwrap.fill(reach_line("d50_um", 45.0, {"median": 95.5, "q05": 88.6, "q95": 104.4}, False,
    ...                                cooling=True), 100))
    target d50_um = 45: not judged at this advice: the vial is at the ceiling, so the plan shown rests
    to the batch end (ending at 95.5 if it did); the next advice, with the vial cooler, plans milling
    again
    """
    head = f"target {key} = {target:g}"
    if end is None:
        return f"{head} is {'reachable' if reachable else 'NOT reachable'} by the batch end"
    m, lo, hi = end["median"], end["q05"], end["q95"]
    if not reachable and cooling:
        return (f"{head}: not judged at this advice: the vial is at the ceiling, so the plan shown rests to the "
                f"batch end (ending at {m:.4g} if it did); the next advice, with the vial cooler, plans milling again")
    if not reachable:
        return f"{head} is NOT reachable by the batch end (predicted median {m:.4g}, 90 % band [{lo:.4g}, {hi:.4g}])"
    if abs(m - target) <= REACH_TOL * abs(target):
        return f"{head} is reachable by the batch end (predicted median {m:.4g})"
    return (f"{head} lies inside the 90 % band of the batch end [{lo:.4g}, {hi:.4g}], but the predicted median "
            f"misses it ({m:.4g}, {100 * (m - target) / target:+.1f} %): reachable only if the mill is not what "
            "the estimate says; samples narrow the band")


def sampling(s_um, tolerance: float) -> dict | None:
    """How closely one sample reads the powder's mean size, and the particle count that would read it
    within ``tolerance`` (relative) at 95 %.

    The relative standard error of a sample mean is cv / sqrt(n) (cv: the sample's coefficient of
    variation of s); n_for_tolerance = ceil((1.96 cv / tolerance)^2).

    Parameters
    ----------
    s_um : array_like
        The sample's particle sizes (um).
    tolerance : float
        Relative error, e.g. the controller's ``[objective] tolerance``.

    Returns
    -------
    dict or None
        ``particles``, ``cv``, ``mean_se_pct`` (one standard error, %), ``mean_95_pct`` (the 95 %
        half-width, %), ``tolerance_pct``, ``particles_for_tolerance``; None for fewer than two
        particles.

    Examples
    --------
    >>> d = sampling([40.0, 60.0] * 50, 0.02)
    >>> d["particles"], round(d["cv"], 4), round(d["mean_se_pct"], 2), d["particles_for_tolerance"]
    (100, 0.201, 2.01, 389)
    """
    s = np.asarray(s_um, dtype=float)
    if s.size < 2 or not tolerance > 0:
        return None
    cv = float(np.std(s, ddof=1) / np.mean(s))
    se = cv / math.sqrt(s.size)
    return {"particles": int(s.size), "cv": cv, "mean_se_pct": 100.0 * se, "mean_95_pct": 100.0 * Z95 * se,
            "tolerance_pct": 100.0 * tolerance, "particles_for_tolerance": int(math.ceil((Z95 * cv / tolerance) ** 2))}


def sampling_note(t_h: float, particles: int) -> str:
    """Why :func:`sampling` gives nothing for the latest sample: fewer than two particles.

    Examples
    --------
    >>> print(sampling_note(0.5, 1))  # doctest: +NORMALIZE_WHITESPACE
    the latest sample (at 0.5 h) holds 1 particle: too few to estimate the spread of sizes, so how closely
    it reads the mean size, and the particle count for the tolerance, are not given (`sampling` is null)
    """
    return (f"the latest sample (at {t_h:g} h) holds {particles} particle{'s' if particles != 1 else ''}: too few "
            "to estimate the spread of sizes, so how closely it reads the mean size, and the particle count for the "
            "tolerance, are not given (`sampling` is null)")


#: a sample update that leaves the filter fewer effective particles than this (its effective sample
#: size, ``ess``, before resampling) is warned of: the 90 % intervals then rest on a handful of
#: particles (each 5 % tail on less than one)
ESS_MIN = 10.0


def band_warning(est: dict, samples: int, particles: int, filter_particles: int) -> list[str]:
    """A warning when the filter's update at a sample node left its weight on fewer than
    :data:`ESS_MIN` effective particles (a near-degenerate filter: its 90 % intervals rest on a
    handful of particles and may be narrower than the samples support). The filter's numbers are
    not changed; the warning says how far to trust them.

    Parameters
    ----------
    est : dict
        The estimate of the node (``t_h``, ``ess``).
    samples, particles : int
        The samples pooled at the node's time and their particles.
    filter_particles : int
        The filter's particle count.

    Examples
    --------
    >>> for w in band_warning({"t_h": 1.0, "ess": 3.04}, 2, 6, 100):
    ...     print(w)  # doctest: +NORMALIZE_WHITESPACE
    filter nearly degenerate at 1 h: the update by 2 samples (6 particles, read as one) left its weight on
    about 3.0 of its 100 particles (effective sample size; warned below 10): the 90 % intervals from 1 h on
    rest on a handful of particles and may be narrower than the samples support
    >>> band_warning({"t_h": 1.0, "ess": 40.0}, 1, 300, 100)
    []
    """
    ess, t = est.get("ess"), est.get("t_h", math.nan)
    if not isinstance(ess, (int, float)) or not math.isfinite(ess) or ess >= ESS_MIN:
        return []
    what = (f"a sample of {particles} particle{'s' if particles != 1 else ''}" if samples == 1 else
            f"{samples} samples ({particles} particles, read as one)")
    return [f"filter nearly degenerate at {t:g} h: the update by {what} left its weight on about {ess:.1f} of its "
            f"{filter_particles} particles (effective sample size; warned below {ESS_MIN:g}): the 90 % intervals "
            f"from {t:g} h on rest on a handful of particles and may be narrower than the samples support"]


def sample_first(estimate: dict, target: dict, tolerance: float, mill_min: int, milled_last: bool,
                 samples_here: int, samples_before: int,
                 samples_max: int = SAMPLES_PER_TIME_MAX) -> str | None:
    """Why another sample should be taken before this advice is acted on, or None.

    The advice's move hinges on the estimate when a target lies inside the estimate's 90 %
    interval and the move is either a correction (milling: it cannot be undone) or a stop (the
    first rest after milling, with the estimate within ``tolerance`` of the target). A fresh sample
    at the same batch time is then worth more than the move: the filter reads both samples as one
    larger sample. Asked only once the campaign has a sample (before it, the estimate is the
    card's prior) and while fewer than ``samples_max`` samples were taken at this batch time.

    Parameters
    ----------
    estimate : dict
        The filter's estimate (``<key>``, ``<key>_q05``, ``<key>_q95``).
    target : dict
        The campaign's targets (key -> value); keys without an interval in ``estimate`` are skipped.
    tolerance : float
        Relative error within which the estimate counts as on target (``[objective] tolerance``).
    mill_min : int
        The advised milling minutes of the next interval.
    milled_last : bool
        Whether the last logged interval milled.
    samples_here, samples_before : int
        Samples taken at this batch time, and at or before it.
    samples_max : int, optional
        Samples at one batch time beyond which no more are asked for.

    Examples
    --------
    >>> est = {"s_mean_um": 55.9, "s_mean_um_q05": 52.6, "s_mean_um_q95": 58.8}
    >>> sample_first(est, {"s_mean_um": 58.0}, 0.02, 15, False, 1, 5)
    's_mean_um 55.9 (90 % 52.6-58.8) brackets the target 58: another sample before milling'
    >>> sample_first(est, {"s_mean_um": 58.0}, 0.02, 15, False, 2, 6) is None  # two taken here already
    True
    >>> sample_first(est, {"s_mean_um": 62.0}, 0.02, 15, False, 1, 5) is None  # outside the interval
    True
    """
    if samples_before < 1 or samples_here >= samples_max:
        return None
    for k, v in target.items():
        lo, hi, m = estimate.get(f"{k}_q05"), estimate.get(f"{k}_q95"), estimate.get(k)
        if lo is None or hi is None or m is None or not lo <= v <= hi:
            continue
        near = abs(m - v) <= tolerance * abs(v)
        if mill_min > 0:
            move = "milling"
        elif milled_last and near:
            move = "stopping"
        else:
            continue
        return f"{k} {m:.4g} (90 % {lo:.4g}-{hi:.4g}) brackets the target {v:g}: another sample before {move}"
    return None
