"""Offline design: the MPC problem solved once over a whole batch from the card's initial state,
turned into an open-loop rpm/rest schedule (the ``[[segment]] hours, rpm`` format that
``bmctl simulate --schedule`` reads), the predicted moments and a figure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io import csv_text, output_set, write_text
from .config import TARGET_KEYS, MPCConfig, format_target



@dataclass
class Design:
    """A designed batch: a phase-pattern schedule (:mod:`bmctl.control.pattern`) and its prediction.

    Attributes
    ----------
    target : dict
        {key: point or (lo, hi)}.
    hours : float
        Batch length designed for (the schedule may end earlier: min_time).
    U : ndarray, (K, 2)
        (rpm, milling 1/0) per segment.
    X : ndarray, (K + 1, 6)
        Moment-model states at the segment ends (exact for the model).
    t_peak_c : ndarray, (K,)
        Highest vial temperature per segment.
    segments : list of (hours, rpm)
    result : PatternResult
    reach : Reach
    pareto : list of PatternResult
        The batch-length sweep behind min_time / min_energy (empty for "target").
    local : PatternResult or None
        The local NLP's result (started from the search's best schedules).
    search : SearchResult
        The global search (its best row per family: ``search.per_family``).
    searched : PatternResult
        The search's answer: the best of its families' schedules integrated as written.
    model : MomentModel or None
        The moment model of the prediction; design.png draws its curves within each segment from it
        (:func:`predicted_path`).
    p : array_like or None
        The model's (gamma_mult, delta_mult) of the prediction (None: (1, 1)).
    """

    card_name: str
    controller_name: str
    target: dict
    hours: float
    ceiling_c: float
    U: np.ndarray
    X: np.ndarray
    t_peak_c: np.ndarray
    segments: list
    result: object
    reach: object
    objective: str = "target"
    pareto: list = field(default_factory=list)
    local: object = None  # the local NLP's PatternResult (None when not run)
    search: object = None  # the global search's SearchResult
    searched: object = None  # the search's best schedule as written (a PatternResult)
    plant: dict | None = None  # the plant check (:func:`plant_check`), when run
    model: object = None  # the moment model predicted with (the figure's curves within segments)
    p: object = None  # its (gamma_mult, delta_mult); None for (1, 1)

    @property
    def times_h(self) -> np.ndarray:
        return np.concatenate([[0.0], np.cumsum([h for h, _ in self.segments])])

    @property
    def done_h(self) -> float:
        """When the schedule is done: its last milling (a trailing rest is not written), at most ``hours``."""
        return float(sum(h for h, _ in self.segments))

    @property
    def switches(self) -> int:
        """On/off switches over the batch, a stop before the batch end included (:func:`batch_switches`)."""
        return batch_switches(self.segments, self.hours)

    @property
    def milling_h(self) -> float:
        return self.result.milling_h

    @property
    def energy_kWh(self) -> float:  # dissipated in the vial: P_max (rpm / rpm_max)^3 x milling hours
        return self.result.energy_kWh

    def family_lines(self) -> list[str]:
        """The best schedule of each family of the search (:meth:`~bmctl.control.reach.Reach.family_lines`),
        a schedule whose peak runs over the ceiling said so: it was not passed over for being farther off."""
        return family_lines(self.reach, self.ceiling_c)


#: RKC substeps of a milling segment at least: a 0.5 h interval's milling phase gets 8 whatever its
#: length (the step the moment model is identified with), so a 5-min burst is integrated as finely as
#: there; with the 2 substeps of 1/16 h, 5-min bursts at 480 rpm every 30 min for 5.5 h ended at
#: 36.0 µm for 34.2 (34.15 with 64 substeps; the plant 34.5)
MILLING_SUBSTEPS_MIN = 8


def simulate_segments(model, segs, p=None):
    """Exact moment-model prediction of (hours, rpm) segments from ``model.x0()`` (the model's own
    integration, segment by segment): (final state, peak T, energy kWh, milling h, states at the ends).

    Parameters
    ----------
    model : MomentModel
    segs : list of (hours, rpm)
        rpm 0 is a rest.
    p : array_like, optional
        (gamma_mult, delta_mult).
    """
    from ..moments.model import n_substeps

    c = model.const
    pp = model.p0() if p is None else np.asarray(p, dtype=float)
    x = model.x0()
    peak, energy, mh, states = float(x[4]), 0.0, 0.0, [x]
    for h, r in segs:
        if r > 0 and n_substeps(h) < MILLING_SUBSTEPS_MIN:  # a short burst: as finely as in a 0.5 h interval
            x = model.step(x, [r, 1.0], h, pp, substeps=MILLING_SUBSTEPS_MIN)
        else:
            x = model.simulate(x, np.array([[r, 1.0 if r > 0 else 0.0]]), h, pp)[-1]
        states.append(x)
        peak = max(peak, float(x[4]))
        if r > 0:
            energy += c.power_max_W * (r / c.rpm_max) ** 3 * h / 1000.0
            mh += h
    return x, peak, energy, mh, states


def interval_segments(rpm, minutes, lengths_min) -> list:
    """(hours, rpm) segments of a schedule on the interval grid (mill first, then rest; equal
    neighbours merged; a trailing rest dropped: it does nothing to the powder).

    Parameters
    ----------
    rpm, minutes, lengths_min : array_like, (K,)

    Examples
    --------
    >>> interval_segments([300, 300, 0], [30, 10, 0], [30, 30, 30])
    [(0.6666666666666666, 300.0)]
    """
    out = []
    for r, a, L in zip(rpm, minutes, lengths_min):
        for mnt, rr in ((float(a), float(r)), (float(L) - float(a), 0.0)):
            if mnt <= 1e-9:
                continue
            if out and abs(out[-1][1] - rr) < 1e-9:
                out[-1][0] += mnt
            else:
                out.append([mnt, rr])
    while len(out) > 1 and out[-1][1] == 0.0:
        out.pop()
    if out and out[-1][1] == 0.0:
        out = []
    return [(mnt / 60.0, r) for mnt, r in out]


def batch_switches(segments, hours: float) -> int:
    """On/off switches of a written schedule over the batch of ``hours`` it was designed for.

    The transitions between its segments (:func:`~bmctl.control.mill.count_switches`) and, where its
    last milling ends before the batch end, that stop: the trailing rest is not written
    (:func:`interval_segments`) but the mill still switches off inside the batch. This is how the
    switch budget (``[mill] max_switches``) is kept: the search's operability test, the phase-pattern
    NLP's constraint and the mill guard of a closed loop all count that stop. A schedule that mills to
    the batch end stops with the batch, which no count includes.

    Parameters
    ----------
    segments : list of (hours, rpm)
        The written schedule (rpm 0 = rest).
    hours : float
        The batch length it was designed for.

    Examples
    --------
    >>> batch_switches([(1.0, 300.0), (0.5, 0.0), (1.0, 300.0)], 3.0)  # on, off, on, and off at 2.5 h
    3
    >>> batch_switches([(1.0, 300.0), (0.5, 0.0), (1.5, 300.0)], 3.0)  # milling to the end
    2
    """
    from .mill import count_switches

    segs = [(h, r) for h, r in segments if h > 1e-12]
    n = count_switches(segs)
    if segs and segs[-1][1] > 0 and sum(h for h, _ in segs) < hours - 1e-9:
        n += 1
    return n


def mill_violations(d: "Design", mill) -> list[str]:
    """The mill's limits a design's written schedule breaks (empty when it runs as written): each
    milling period and rest at least its minimum (a trailing one may be shorter), rpm on the dial's
    step and at least the lowest milling speed (:func:`~bmctl.control.mill.check_schedule`), and its
    switches over the batch (:func:`batch_switches`) within ``max_switches``.

    Parameters
    ----------
    d : Design
    mill : bmctl.control.config.Mill
        The controller's ``[mill]`` table.
    """
    from .mill import check_schedule

    out = check_schedule([(h, r) for h, r in d.segments if h > 1e-12], mill, switches=d.switches)
    return out if len(out) <= 3 else out[:2] + [f"{len(out) - 2} more"]


def switches_of(r) -> int:
    """:func:`batch_switches` of a design result (a :class:`~bmctl.control.pattern.PatternResult`)."""
    return batch_switches(r.segments, r.hours)


def switches_text(n: int) -> str:
    """"1 on/off switch", "14 on/off switches"."""
    return f"{n} on/off switch{'' if n == 1 else 'es'}"


@dataclass
class Searched:
    """The global search's answer as written: its best schedule and each family's best row, each a
    :class:`~bmctl.control.pattern.PatternResult` of the moment model's integration of the written schedule."""

    best: object
    by_family: dict


def searched_pattern(model, cfg, target: dict, hours: float, p=None):
    """The global search's best operable schedule for a batch of ``hours`` from the card's state, as a
    :class:`Searched` (exact moment-model numbers), with the search result and the grid.

    Parameters
    ----------
    model : MomentModel
    cfg : MPCConfig
    target : dict
    hours : float
    p : array_like, optional
    """
    import time

    from .outputs import output_dict, relative_error
    from .pattern import PatternResult
    from .planner import plan_binding
    from .search import Carry, expand, limits_of, make_grid, search

    t0 = time.perf_counter()
    pp = model.p0() if p is None else np.asarray(p, dtype=float)
    grid = make_grid(0.0, hours, cfg.interval_h)
    lim = limits_of(cfg, model)
    ps = cfg.plan
    sr = search(model, model.x0()[None], pp[None], target, grid, lim, cfg.weights, Carry(),
                substeps=(max(MILLING_SUBSTEPS_MIN, ps.onset_substeps or 0), ps.substeps),
                rpm_step=ps.rpm_step, band=ps.error_band, rounds=max(2, ps.rounds), keep=8, coarse_factor=1)
    L = grid.lengths_min
    binding = plan_binding(sr, grid, lim, Carry(), cfg.temperature.ceiling_c)

    def written(rpm, minutes, family, rms):
        segs = interval_segments(rpm, minutes, L)
        x, peak, energy, mh, states = simulate_segments(model, segs, pp)
        outs = output_dict(x)
        err = max((relative_error(outs[k], v) for k, v in target.items()), default=0.0)
        return PatternResult(float(hours), np.array(rpm, dtype=float), minutes / L, np.ones(grid.K),
                             (minutes < L).astype(float), segs, x, peak, energy, mh, err, outs, 0.0, float(rms),
                             "search", f"{family}, {sr.evaluated} schedules", 0.0, states, list(binding), family)

    # The search ranks its rows by a cheaper integration that drifts over long batches (a 48 h row at
    # 0.04 % is 3.3 % off as written); each family's best row is integrated as written and the best of
    # those is the search's answer (the rule design_one applies between the search and the local NLP).
    by_family, same = {}, False
    for fam, row in sr.per_family.items():
        if "params" in row:
            rpm, minutes = expand(np.asarray(row["params"], dtype=float)[None], grid, lim)
            by_family[fam] = written(rpm[0], minutes[0], fam, row.get("rms", sr.rms))
            same |= fam == sr.family and np.array_equal(rpm[0], sr.rpm) and np.array_equal(minutes[0], sr.minutes)
    res = by_family[sr.family] if same else written(sr.rpm, sr.minutes, sr.family, sr.rms)
    tol, band = cfg.objective.tolerance, cfg.plan.error_band
    for fam, cand in by_family.items():
        if fam != sr.family and _better(cand, res, tol, band, cfg.temperature.ceiling_c, cfg.weights):
            res = cand
    res.solve_s = time.perf_counter() - t0
    return Searched(res, by_family), sr, grid


def _better(a, b, tol: float, band: float, ceiling_c: float, weights) -> bool:
    """Whether design result ``a`` beats ``b``: under the ceiling first, then the lower error unless
    both are within ``band`` of each other (then the lower energy, milling-time and switch cost)."""
    def key(r):
        return (weights.energy_per_kWh * r.energy_kWh + weights.time_per_h * r.milling_h
                + getattr(weights, "switch", 0.0) * switches_of(r))

    oa, ob = a.peak_c <= ceiling_c + 0.05, b.peak_c <= ceiling_c + 0.05
    if oa != ob:
        return oa
    ea, eb = max(a.error, 0.0), max(b.error, 0.0)
    if abs(ea - eb) > band:
        return ea < eb
    return key(a) < key(b) - 1e-12


def design_one(model, target: dict, hours: float, cfg, p=None, method: str = "relax-round", local: bool = True):
    """Global search, then the phase-pattern NLP started from its best schedules; the better of the two.

    Parameters
    ----------
    model : MomentModel
    target : dict
    hours : float
    cfg : MPCConfig
    p : array_like, optional
    method : str
        "relax-round" or "bonmin" (the local solve).
    local : bool
        Run the local NLP.

    Returns
    -------
    (PatternResult, PatternResult or None, SearchResult, Searched)
        The chosen result, the local NLP's (None when not run), the search's, and the search's
        schedules as written (:func:`searched_pattern`).
    """
    from .pattern import PatternDesigner

    searched, sr, grid = searched_pattern(model, cfg, target, hours, p)
    res_s = searched.best
    res_l = None
    if local:
        d = PatternDesigner(model, hours, cfg, target, p)
        fams = sorted(sr.per_family.values(), key=lambda f: (f["error"], f["energy_kWh"]))
        from .search import expand, limits_of

        rows = [np.asarray(sr.params)] + [np.asarray(f["params"]) for f in fams if f["family"] != sr.family][:1]
        starts = []
        for row in rows:
            r, m = expand(row[None], grid, limits_of(cfg, model))
            starts.append(d.start_from(r[0], m[0], grid.interval_min))
        d.starts = starts
        res_l = d.solve(method)
    tol, band = cfg.objective.tolerance, cfg.plan.error_band
    best = res_s
    if res_l is not None and _better(res_l, res_s, tol, band, cfg.temperature.ceiling_c, cfg.weights):
        best = res_l
    return best, res_l, sr, searched


#: the shortest batch design plans (min): its schedule is written in whole minutes
BATCH_MIN_MIN = 5.0


def check_batch(hours: float, cfg: MPCConfig, objective: str | None = None, hours_source: str = "hours",
                cfg_source: str = "controller") -> None:
    """Refuse a batch, or a batch length of the min_time / min_energy sweep, shorter than the mill's
    minimum milling period (and :data:`BATCH_MIN_MIN`): its schedule would be segments of seconds,
    under that period, that ``bmctl simulate --schedule`` refuses.

    Parameters
    ----------
    hours : float
        Batch length (h).
    cfg : MPCConfig
        Its ``interval_h`` and ``[objective]`` (kind and sweep).
    objective : str, optional
        "target", "min_time" or "min_energy" (default: ``cfg.objective.kind``).
    hours_source, cfg_source : str, optional
        The flag (or card field) that gave ``hours`` and the controller file, named in the messages.

    Examples
    --------
    >>> from bmctl.control.config import validate_controller
    >>> cfg = validate_controller({"kind": "mpc", "interval_h": 0.5}, "c.toml")
    >>> check_batch(0.25, cfg), check_batch(1.0, cfg, "min_time")
    (None, None)
    >>> check_batch(0.02, cfg, hours_source="--hours", cfg_source="c.toml")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    bmctl.errors.InputError: --hours: a batch of 0.02 h (1.2 min) is shorter than the 5 min a schedule of whole minutes needs ...
    >>> check_batch(0.1, cfg, "min_time", "--hours", "c.toml")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    bmctl.errors.InputError: c.toml: objective.sweep: 0.25 of --hours 0.1 h is a batch of 1.5 min, shorter than ...
    """
    shortest = max(BATCH_MIN_MIN, float(cfg.mill.min_mill_min)) / 60.0  # h
    why = (f"shorter than the {shortest * 60:g} min a schedule of whole minutes needs (the mill's minimum milling "
           f"period in {cfg_source}, at least {BATCH_MIN_MIN:g} min)")
    if hours < shortest - 1e-9:
        raise InputError(f"{hours_source}: a batch of {hours:g} h ({hours * 60:.4g} min) is {why}")
    if (objective or cfg.objective.kind) == "target":
        return
    frac = min(cfg.objective.sweep)
    if hours * frac < shortest - 1e-9:
        raise InputError(f"{cfg_source}: objective.sweep: {frac:g} of {hours_source} {hours:g} h is a batch of "
                         f"{hours * frac * 60:.3g} min, {why}")


def design_schedule(model, target: dict, hours: float, cfg: MPCConfig, p=None, objective: str | None = None,
                    method: str | None = None, local: bool = True, progress=None) -> Design:
    """Design a schedule over ``hours`` from ``model.x0()`` under the mill's limits: a global search
    over operable schedule families (:mod:`bmctl.control.search`), then the phase-pattern NLP
    (:mod:`bmctl.control.pattern`) started from its best schedules; the better of the two.

    Parameters
    ----------
    model : MomentModel
    target : dict
        {key: point or (lo, hi)}, keys from :data:`TARGET_KEYS`.
    hours : float
        Batch length: at least one control interval, as each batch length of the min_time /
        min_energy sweep (:func:`check_batch`).
    cfg : MPCConfig
        Bounds, ceiling, weights, ``[mill]``, ``[objective]`` and ``[plan]`` (the search).
    p : array_like, optional
        (gamma_mult, delta_mult); default (1, 1).
    objective : str, optional
        "target", "min_time" or "min_energy" (default: ``cfg.objective.kind``).
    method : str, optional
        "relax-round" or "bonmin" (default: ``cfg.objective.integer_method``).
    local : bool, optional
        Run the local NLP after the search (default True).
    progress : callable, optional
        Called with one line of text per step.
    """
    from .reach import Reach

    if not (isinstance(hours, (int, float)) and math.isfinite(hours) and hours > 0):
        raise InputError(f"hours: must be a finite number > 0 (got {hours})")
    if not target:
        raise InputError("target: names no moment")
    obj = objective or cfg.objective.kind
    check_batch(hours, cfg, obj)
    from .base import check_rpm_range

    check_rpm_range(cfg, model.rpm_max)  # every input check before the first progress line
    say = progress or (lambda text: None)
    meth = method or cfg.objective.integer_method
    tol = cfg.objective.tolerance
    pareto = []
    if obj == "target":
        say(f"searching operable schedules over {hours:g} h, then the local NLP")
        res, res_l, sr, searched = design_one(model, target, hours, cfg, p, meth, local)
    else:
        runs = []
        for frac in sorted(cfg.objective.sweep):
            say(f"batch of {hours * frac:g} h: searching, then the local NLP")
            runs.append(design_one(model, target, hours * frac, cfg, p, meth, local))
        pareto = [r[0] for r in runs]
        ok = [i for i, r in enumerate(pareto) if r.error <= tol]
        if not ok:
            i = min(range(len(pareto)), key=lambda j: pareto[j].error)
        elif obj == "min_time":
            i = min(ok, key=lambda j: (pareto[j].hours, pareto[j].energy_kWh))
        else:
            i = min(ok, key=lambda j: (pareto[j].energy_kWh, pareto[j].hours))
        res, res_l, sr, searched = runs[i]
    families = written_families(sr.per_family, searched.by_family)
    if res.error <= tol:
        reach = Reach(True, res.error, res.outputs, [], families)
    else:
        binding = list(res.active)
        if not binding:  # a rest or a short milling closest, no limit met: is it the batch time?
            why = batch_time_binding(model, target, float(res.hours), cfg, p)
            binding = [why] if why else []
        reach = Reach(False, res.error, res.outputs, binding, families)
    segs = res.segments
    X = np.array(res.seg_states)
    if not segs:  # the best plan mills nothing: a rest over the whole batch (a schedule of one segment)
        segs = [(float(res.hours), 0.0)]
        X = np.array([X[0], np.asarray(model.step(X[0], np.array([0.0, 0.0]), float(res.hours)), float)])
    U = np.array([[r, 1.0 if r > 0 else 0.0] for _, r in segs]).reshape(-1, 2)
    Tpk = np.maximum(X[:-1, 4], X[1:, 4]) if len(segs) else np.zeros(0)
    d = Design(model.card.card.name, cfg.name, dict(target), float(res.hours), cfg.temperature.ceiling_c,
               U, X, Tpk, segs, res, reach, obj, pareto)
    d.local = res_l
    d.search = sr
    d.searched = searched.best
    d.model, d.p = model, p
    return d


def family_lines(reach, ceiling_c: float) -> list[str]:
    """One line per schedule family (:meth:`~bmctl.control.reach.Reach.family_lines`); a family whose
    best schedule peaks over ``ceiling_c`` (by more than the search's tolerance) ends "over the ceiling".

    Parameters
    ----------
    reach : Reach
        Its ``per_family`` rows carry ``peak_c`` (:func:`written_families`).
    ceiling_c : float
        The vial-temperature ceiling.

    Examples
    --------
    >>> from bmctl.control.reach import Reach
    >>> row = {"error": 0.072, "peak_c": 26.9, "switches": 5, "schedule": "100 rpm, 2.50 h milling"}
    >>> family_lines(Reach(False, 0.1, {}, [], {"two-phase": row}), 25.1)[0].split("  ")[-1]
    'over the ceiling (25.1 °C)'
    """
    from .search import CEILING_TOL_C

    lines = reach.family_lines()
    for i, v in enumerate(reach.per_family.values()):
        if float(v["peak_c"]) > ceiling_c + CEILING_TOL_C:
            lines[i] += f"  over the ceiling ({ceiling_c:g} °C)"
    return lines


def batch_time_binding(model, target: dict, hours: float, cfg, p=None) -> str:
    """Whether the batch time is what keeps a target out of reach when no limit binds the closest
    schedule (a rest, or milling that stops short): milling throughout to the batch end at every speed
    on the dial still misses, under the ceiling, and milling on at one speed reaches the target later.
    The phrase for the design's ``binding``, or "" when that is not so (a schedule of moment-model
    trajectories only: nothing of the design changes).

    Continuous milling from the card's state at each dial speed (at most 41 of them) is integrated in
    steps of at most 0.25 h (at most 240 to the batch end) to the batch end and on to
    ``max(4 hours, the card's process.hours)``.

    Parameters
    ----------
    model : MomentModel
    target : dict
    hours : float
        The batch length designed for.
    cfg : MPCConfig
        Bounds, ceiling, mill limits and ``[objective] tolerance``.
    p : array_like, optional
    """
    from .config import target_bounds
    from .outputs import output_values
    from .search import CEILING_TOL_C, limits_of

    lim = limits_of(cfg, model)
    tol = cfg.objective.tolerance
    pp = model.p0() if p is None else np.asarray(p, dtype=float)
    n_b = max(1, min(240, math.ceil(hours / 0.25 - 1e-9)))
    dt = hours / n_b
    n = max(n_b + 1, math.ceil(max(4.0 * hours, float(model.card.process.hours)) / dt - 1e-9))
    st = lim.rpm_step if lim.rpm_step > 0 else 10.0
    dial = np.arange(lim.rpm_lo, lim.rpm_hi + 1e-9, st)
    if dial.size > 41:
        dial = dial[np.unique(np.linspace(0, dial.size - 1, 41).round().astype(int))]
    keys = list(target)
    end_best, later = None, None  # (error at the batch end, rpm); (hours to reach, rpm)
    for r in dial:
        X = model.simulate(model.x0(), np.tile([float(r), 1.0], (n, 1)), dt, pp)
        err = np.zeros(X.shape[0])
        for k, y in zip(keys, output_values(X, keys)):
            lo, hi = target_bounds(target[k])
            y = np.asarray(y, dtype=float).reshape(-1)
            err = np.maximum(err, np.maximum(y - hi, lo - y).clip(min=0.0) / max(abs(0.5 * (lo + hi)), 1e-12))
        cool = np.maximum.accumulate(X[:, 4]) <= lim.ceiling_c + CEILING_TOL_C  # the peak so far under the ceiling
        if cool[n_b] and (end_best is None or err[n_b] < end_best[0]):
            end_best = (float(err[n_b]), float(r))
        hit = np.flatnonzero(cool & (err <= tol))
        if hit.size and hit[0] <= n_b:
            return ""  # milling at this speed (then resting) reaches it within the batch: not the batch time
        if hit.size and (later is None or hit[0] * dt < later[0]):
            later = (float(hit[0] * dt), float(r))
    if end_best is None or later is None:
        return ""
    return (f"batch time ({hours:g} h): milling throughout to the batch end still misses (at best "
            f"{100 * end_best[0]:.1f} % off, at {end_best[1]:g} rpm); milling on at {later[1]:g} rpm reaches the target "
            f"after {later[0]:.3g} h")


def written_families(per_family: dict, by_family: dict) -> dict:
    """The search's best row per family with the numbers of its schedule as written.

    ``switches`` are those of the written schedule over the batch (:func:`batch_switches`): a stop of
    the last milling period before the batch end counts, as the search's budget counts it, although
    the written schedule drops the trailing rest (:func:`interval_segments`); the design's summary,
    schedule.toml and figure count the same way. ``error`` and ``peak_c`` are those of the moment
    model's own integration of the written schedule (:func:`simulate_segments`), as the design's
    summary reports its schedule; the search's cheaper prediction, which ranked the rows, can be a
    few per cent off (kept as ``search_error``).

    Parameters
    ----------
    per_family : dict
        ``SearchResult.per_family`` ({family: dict with ``params``, ``switches``, ...}).
    by_family : dict
        {family: PatternResult} of each row's written schedule (:attr:`Searched.by_family`).

    Returns
    -------
    dict
        A copy of ``per_family`` with ``switches``, ``error`` and ``peak_c`` as written.
    """
    out = {}
    for fam, row in per_family.items():
        w = by_family[fam]
        out[fam] = {**row, "switches": switches_of(w), "search_error": row.get("error"), "peak_c": float(w.peak_c),
                    "error": w.error}
    return out


def plant_check(card, segments, target: dict, seeds: int = 3, particles: int = 5000, seed: int = 0,
                workers: int | None = None, scheduler: str | None = None) -> dict:
    """The plant's result for a schedule: a small seeded ensemble (on Dask when it pays).

    Plant k draws from ``SeedSequence(seed).spawn(seeds)[k]``; the numbers do not depend on the
    worker count.

    Parameters
    ----------
    card : ModelCard
        The plant's card.
    segments : list of (hours, rpm)
    target : dict
    seeds, particles, seed : int
    workers, scheduler : optional
        As ``bmctl whatif`` (default: serial for a small ensemble, :func:`bmctl.parallel.auto_workers`).

    Returns
    -------
    dict
        ``{key: {"mean", "min", "max"}}`` for every target key and ``temperature_peak_c``, ``seeds``; a
        D-value key (``d10_um, d50_um, d90_um, span``: the plants' particles, volume-weighted) also
        has ``law_mean``, the same through the size law of each plant's number mean and std (the
        closed form the moment model's prediction and the controller use).
    """
    from ..parallel import auto_workers, client_for, close_client, map_seeded, seed_sequences

    hours = sum(h for h, _ in segments)
    task = (card, tuple((float(h), float(r)) for h, r in segments), int(particles))
    cpu_s = 0.6 * hours * particles / 5000.0 * seeds  # ~2.6 s per 12 h plant of 5000 particles
    n = auto_workers(seeds, cpu_s, workers, scheduler)
    client = client_for(scheduler, n) if (scheduler or n) else None
    try:
        members = map_seeded(_plant_member, [task] * seeds, seed_sequences(seed, seeds), client)
    finally:
        if client is not None:
            close_client(client)
    from ..stats import DVALUE_QUANTILES, law_size_stats

    out = {"seeds": int(seeds), "particles": int(particles)}
    for k in list(target) + ["s_mean_um", "temperature_c"]:
        v = np.array([m[0][k] for m in members], dtype=float)
        out[k] = {"mean": float(v.mean()), "min": float(v.min()), "max": float(v.max())}
        if k in DVALUE_QUANTILES or k == "span":  # the plant's particles' D-value; the law's, as the model steers
            law = [float(law_size_stats(m[0]["s_mean_um"], m[0]["s_std_um"])[k]) for m in members]
            out[k]["law_mean"] = float(np.mean(law))
    out["temperature_peak_c"] = float(max(m[1] for m in members))
    return out


def _plant_member(task, rng) -> tuple:
    """One plant on the schedule: (final moments, peak vial temperature)."""
    from ..loop import run_open_loop
    from ..plant.plant import Plant

    card, segs, particles = task
    plant = Plant(card, rng, particles)
    peak = [plant.temperature_c]
    run_open_loop(plant, list(segs), 0.05, lambda t, mill: peak.append(mill.temperature_c))
    return plant.moments(), max(peak)


def pareto_table(d: Design) -> str:
    """The batch-length sweep as a markdown table: time, energy, final error, switches, peak T."""
    rows = ["| batch h | milling h | energy kWh | final error % | switches | peak T °C |", "|---|---|---|---|---|---|"]
    for r in d.pareto:
        rows.append(f"| {r.hours:.2f} | {r.milling_h:.2f} | {r.energy_kWh:.4g} | {100 * r.error:.2f} | "
                    f"{switches_of(r)} | {r.peak_c:.1f} |")
    return "\n".join(rows)


def done_text(d: Design) -> str:
    """When the schedule is done, where that is before the end of the batch it was designed for
    (its last milling; the trailing rest is not written); "" when it runs the whole batch.

    Parameters
    ----------
    d : Design
    """
    done = d.done_h
    if done >= d.hours - 1e-9:
        return ""
    text = (f"the schedule is done after {done:.2f} h (its last milling, then nothing to run; that stop counts as "
            "an on/off switch); ")
    if d.objective == "target" or not d.pareto:
        return text + f"{d.hours:g} h is the batch length it was designed for"
    if not d.reach.reachable:
        return text + f"{d.hours:g} h is the batch length of the sweep that came closest to the target"
    if d.objective == "min_time":
        shortest = min(r.hours for r in d.pareto)
        which = "tried" if d.hours <= shortest + 1e-9 else "within the tolerance"
        return text + f"{d.hours:g} h is the shortest batch length the sweep {which}"
    return text + f"{d.hours:g} h is the batch length of the sweep with the least energy within the tolerance"


def schedule_toml(d: Design) -> str:
    """The schedule as TOML text (``bmctl simulate --schedule`` format).

    Each segment's comment gives its length in minutes (:func:`bmctl.schedule.minutes_text`); the
    header says that the times are whole minutes only where every one is: a segment that fills out
    a control interval of a fractional number of minutes (a batch that is not a whole number of
    minutes, or ``interval_h = 0.33``) is written with its decimals and counted in the header. The name
    and segments are written as :meth:`bmctl.schedule.Schedule.toml` writes them, so that the file reads
    back to the same lengths and speeds.

    Parameters
    ----------
    d : Design
    """
    from ..schedule import Schedule, is_whole_minutes

    tgt = ", ".join(f"{k} = {format_target(v)}" for k, v in d.target.items())
    last = d.X[-1]
    r = d.result
    done = done_text(d)
    lines = [
        f"# Designed by `bmctl design` for {d.card_name}: target {tgt} at {d.hours:g} h (objective {d.objective})"
        + (f"; {done}" if done else ""),
        f"# controller {d.controller_name or 'mpc'}; {r.method}: {r.status}, {r.solve_s:.1f} s; "
        f"{switches_text(d.switches)}; predicted "
        + ", ".join(f"{k} {r.outputs[k]:.4g}" for k in d.target if k in r.outputs)
        + f" (error {100 * r.error:.2f} %)",
        f"# predicted (moment model): s mean {last[0]:.2f} µm, s std {last[1]:.2f} µm, r mean {last[2]:.4f}, "
        f"r std {last[3]:.4f}; peak vial T {np.max(d.t_peak_c):.1f} °C (ceiling {d.ceiling_c:g} °C)",
        "# rpm 0 = rest; " + _minutes_note([h for h, _ in d.segments], is_whole_minutes),
    ]
    if d.plant:
        pc = d.plant
        plants = f"{pc['seeds']} plant{'s' if pc['seeds'] != 1 else ''}"
        lines.append(f"# plant check ({plants} of {pc['particles']} particles): "
                     + ", ".join(f"{k} {pc[k]['mean']:.4g} [{pc[k]['min']:.4g}, {pc[k]['max']:.4g}]" for k in d.target)
                     + f"; peak vial T {pc['temperature_peak_c']:.1f} °C")
    # name and segments as Schedule.toml writes them: numbers that read back exactly, the name quoted
    return "\n".join(lines) + "\n" + Schedule.from_pairs(d.segments, f"design-{d.card_name}").toml()


def _minutes_note(hours, is_whole) -> str:
    """The header's note on the segments' minutes: whole, or how many are not.

    Parameters
    ----------
    hours : list of float
        The segments' lengths (h).
    is_whole : callable
        Whether a length is a whole number of minutes (:func:`bmctl.schedule.is_whole_minutes`).

    Examples
    --------
    >>> from bmctl.schedule import is_whole_minutes
    >>> _minutes_note([0.5, 0.25], is_whole_minutes)
    'milling times are whole minutes'
    >>> _minutes_note([0.09], is_whole_minutes)  # doctest: +ELLIPSIS
    'times are whole minutes but for 1 of 1 segment, which fills out a control interval of a fractional ...'
    """
    odd = sum(not is_whole(h) for h in hours)
    if not odd:
        return "milling times are whole minutes"
    return (f"times are whole minutes but for {odd} of {len(hours)} segment{'s' if len(hours) != 1 else ''}, "
            f"which fill{'s out a control interval' if odd == 1 else ' out control intervals'} of a fractional number "
            f"of minutes ({'its' if odd == 1 else 'their'} minutes shown with decimals)")


def predicted_csv(d: Design) -> str:
    """The design's ``predicted.csv``: a row per segment start (and the batch end), the action over
    it, the moment-model state, and the target (``target_K``, or ``target_K_lo``/``_hi`` for a window)."""
    from .config import target_bounds

    tcols, tvals = [], []
    for key, value in d.target.items():
        lo, hi = target_bounds(value)
        tcols += [f"target_{key}"] if lo == hi else [f"target_{key}_lo", f"target_{key}_hi"]
        tvals += [lo] if lo == hi else [lo, hi]
    header = ["t_h", "rpm", "milling", "t_peak_c", "s_mean_um", "s_std_um", "r_mean", "r_std", "temperature_c",
              "hardening"] + tcols
    rows = []
    t = d.times_h
    for k in range(d.X.shape[0]):
        # each row: a segment's start state and the action over it; the last row, the batch end, has none (empty)
        act = [float(d.U[k, 0]), float(d.U[k, 1]), float(d.t_peak_c[k])] if k < d.U.shape[0] else ["", "", ""]
        rows.append([float(t[k]), *act, *map(float, d.X[k])] + tvals)
    return csv_text(header, rows)


#: points of design.png's predicted curves over the batch (at least; every segment end is one)
FIGURE_POINTS = 300


def predicted_path(d: Design, points: int = FIGURE_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """The moment-model prediction within each segment, as design.png draws it.

    Each segment is integrated from its start state in pieces of whole substeps of
    :func:`simulate_segments`'s own integration (the same substeps and stages, so the pieces add up
    to the segment as predicted); a rest in pieces of about ``end / points``. Without the model
    (``d.model`` None) only the segment ends are known.

    Parameters
    ----------
    d : Design
    points : int, optional
        About how many points over the batch.

    Returns
    -------
    t : ndarray, (N,)
        Batch times (h), every segment end among them.
    X : ndarray, (N, 6)
        States at ``t``; ``d.X`` exactly at the segment ends.
    """
    t_end = d.times_h
    X_end = np.asarray(d.X, dtype=float)
    if d.model is None:
        return t_end, X_end
    from ..moments.model import n_substeps

    pp = d.model.p0() if d.p is None else np.asarray(d.p, dtype=float)
    dt = max(float(d.hours), float(t_end[-1])) / max(int(points), 1)
    ts, xs = [float(t_end[0])], [X_end[0]]
    for k, (h, _) in enumerate(d.segments):
        h, u = float(h), np.asarray(d.U[k], dtype=float)
        if u[0] > 0 and u[1] > 0:  # milling: pieces of whole substeps of the segment's own integration
            n = max(n_substeps(h), MILLING_SUBSTEPS_MIN)  # as simulate_segments integrates it
            q = max(1, int(dt / (h / n)))
            sizes = [q] * (n // q) + ([n % q] if n % q else [])
        else:  # a rest: the powder is unchanged, the temperature exact over any piece
            sizes = [1] * max(1, int(math.ceil(h / dt - 1e-9)))
            n = len(sizes)
        x, t = X_end[k], float(t_end[k])
        for m in sizes[:-1]:
            x = np.asarray(d.model.step(x, u, m * h / n, pp, substeps=m), dtype=float)
            t += m * h / n
            ts.append(t)
            xs.append(x)
        ts.append(float(t_end[k + 1]))  # the last piece's end: the segment's state as predicted
        xs.append(X_end[k + 1])
    return np.asarray(ts), np.vstack(xs)


def design_figure(d: Design, path: Path) -> None:
    """Schedule (rpm per segment, rests shaded), size moments and D50 (µm), span, r, vial temperature,
    over the batch designed for (0 to ``d.hours``, also where the schedule is done earlier); the
    predicted curves run through each segment (:func:`predicted_path`), not straight from one
    segment end to the next. With a plant check (``d.plant``) its ensemble's mean and range are
    drawn at the schedule's end beside each curve it gives, and its peak vial temperature as a line."""
    from ..io import pyplot, savefig
    from ..plots import R_LABEL, quantity_label
    from .config import target_bounds
    from .outputs import output_values

    plt = pyplot()
    t = d.times_h
    end = max(float(d.hours), float(t[-1]))
    tp, X = predicted_path(d)  # the curves; t, d.X: the segment ends (the schedule and predicted.csv)
    within = d.model is not None
    d50 = np.asarray(output_values(X, ["d50_um"])[0], dtype=float)
    sizes = (("s_mean_um", X[:, 0]), ("s_std_um", X[:, 1]), ("d50_um", d50))
    if "d90_um" in d.target:  # drawn with its target line, as the other sizes
        sizes += (("d90_um", np.asarray(output_values(X, ["d90_um"])[0], dtype=float)),)
    span = (("span", np.asarray(output_values(X, ["span"])[0], dtype=float)),)
    shape = (("r_mean", X[:, 2]), ("r_std", X[:, 3]))

    pc = d.plant  # the plant check (:func:`plant_check`), None where it was not run
    checked = pc or {}

    def n_entries(series):  # curves, target lines and the plant check's targeted markers
        return len(series) + sum((k in d.target) * (1 + (k in checked)) for k, _ in series)

    # fixed layout in inches (tight_layout and a tight bounding box would each draw the figure once more
    # to measure it): the rpm schedule across the top, then two rows of two panels, each legend above its
    # panel (inside, it hid the target window it names)
    W, left, right, gap = 11.0, 0.8, 0.3, 0.95
    pw = (W - left - right - gap) / 2
    ph, rpm_h, leg_row = 2.05, 1.45, 0.165
    rows = [max(n_entries(sizes), n_entries(span)), max(n_entries(shape), 2 + (pc is not None))]
    leg = [0.12 + leg_row * int(np.ceil(n / 2)) for n in rows]
    # the rpm panel keeps its time labels: it is twice as wide as the panels below, whose labels do not fit it
    heights = [0.55, 0.3, rpm_h, 0.45 + leg[0], ph, 0.2 + leg[1], ph, 0.55]
    H = sum(heights)
    fig = plt.figure(figsize=(W, H))

    def box(col, y_top, h, width=pw):
        return [(left + col * (pw + gap)) / W, (H - y_top - h) / H, width / W, h / H]

    y = heights[0] + heights[1]
    ax_rpm = fig.add_axes(box(0, y, rpm_h, 2 * pw + gap))
    y += rpm_h + heights[3]
    ax_size = fig.add_axes(box(0, y, ph), sharex=ax_rpm)
    ax_span = fig.add_axes(box(1, y, ph), sharex=ax_rpm)
    y += ph + heights[5]
    ax_r = fig.add_axes(box(0, y, ph), sharex=ax_rpm)
    ax_temp = fig.add_axes(box(1, y, ph), sharex=ax_rpm)
    panels = (ax_rpm, ax_size, ax_span, ax_r, ax_temp)

    rpm = d.U[:, 0] * (d.U[:, 1] > 0)
    rests = [(t[k], t[k + 1]) for k in range(len(rpm)) if rpm[k] <= 0]
    stopped = end > t[-1] + 1e-9
    for ax in panels:
        for j, (a, b) in enumerate(rests):
            ax.axvspan(a, b, color="0.88", lw=0, zorder=0, label="rest (rpm 0)" if j == 0 else None)
        if stopped:
            ax.axvspan(t[-1], end, facecolor="none", edgecolor="0.78", hatch="//", lw=0, zorder=0,
                       label="schedule done: mill stopped to the batch end")
        ax.grid(alpha=0.3)
    ax = ax_rpm
    if stopped:  # the mill stands still from the schedule's end to the batch end
        ax.step(np.append(t, end), np.append(rpm, [0.0, 0.0]), where="post", color="tab:blue", label="rpm (0 = rest)")
    else:
        ax.step(t, np.append(rpm, rpm[-1:]), where="post", color="tab:blue", label="rpm (0 = rest)")
    ax.set_ylim(0, 1.12 * max(float(rpm.max(initial=0.0)), 1.0))
    ax.set_xlim(0, end)
    ax.set_ylabel("rpm")
    ax.set_title(f"schedule: {switches_text(d.switches)}, {d.hours:g} h batch", loc="left", fontsize=10)
    h, lab = ax.get_legend_handles_labels()
    ax.legend(h[-1:] + h[:-1], lab[-1:] + lab[:-1], fontsize=7.5, loc="lower right", bbox_to_anchor=(1.0, 1.0), ncol=3,
              frameon=False, borderaxespad=0.2)
    # without the model, only the segment ends are predicted: marked, the lines between them only join them
    style = {} if within else {"marker": "o", "ms": 3}
    for ax, series, lab in ((ax_size, sizes, "particle size s (µm)"), (ax_span, span, quantity_label("span")),
                            (ax_r, shape, R_LABEL)):
        for key, yv in series:
            name = "predicted span" if key == "span" else quantity_label(key)
            line, = ax.plot(tp, yv, label=name, **style)
            if key in d.target:
                name = "span" if key == "span" else name
                lo, hi = target_bounds(d.target[key])
                if hi > lo:
                    ax.axhspan(lo, hi, color=line.get_color(), alpha=0.15, label=f"target window {name}")
                else:
                    ax.axhline(lo, color=line.get_color(), ls="--", lw=1, label=f"target {name}")
        ax.set_ylabel(lab)
    if pc is not None:  # the plant check at the schedule's end: the ensemble's mean, its range as a bar
        plants = f"plant check ({pc['seeds']} plant{'s' if pc['seeds'] != 1 else ''})"
        for ax, series in ((ax_size, sizes), (ax_span, span), (ax_r, shape)):
            for j, (key, _) in enumerate(series):
                if key in pc:
                    m = pc[key]
                    ax.errorbar([t[-1]], [m["mean"]], yerr=[[m["mean"] - m["min"]], [m["max"] - m["mean"]]],
                                fmt="D", ms=5, color=f"C{j}", mec="k", ecolor="k", capsize=3, zorder=5,
                                label=f"{plants}: {quantity_label(key)}" if key in d.target else None)
    ax = ax_temp
    ax.plot(tp, X[:, 4], color="tab:red", label="vial temperature" if within else "vial temperature at segment ends",
            **style)
    if pc is not None:
        ax.axhline(pc["temperature_peak_c"], color="tab:red", ls=":", lw=1.2,
                   label=f"{plants}: peak {pc['temperature_peak_c']:.1f} °C")
    ax.axhline(d.ceiling_c, color="k", ls="--", lw=1, label=f"ceiling {d.ceiling_c:g} °C")
    ax.set_ylabel("vial temperature (°C)")
    for ax in (ax_size, ax_span, ax_r, ax_temp):  # only the curves and targets: the shading is explained above
        h, lab = ax.get_legend_handles_labels()
        keep = [i for i, s in enumerate(lab) if not s.startswith(("rest", "schedule done"))]
        ax.legend([h[i] for i in keep], [lab[i] for i in keep], fontsize=7.5, loc="lower left",
                  bbox_to_anchor=(0.0, 1.0), ncol=2, frameon=False, borderaxespad=0.2)
    for ax in (ax_size, ax_span):
        ax.tick_params(labelbottom=False)
    for ax in (ax_r, ax_temp):
        ax.set_xlabel("batch time t (h)")
    marker_note = "" if pc is None else "; ◆ plant check: mean and range"
    fig.suptitle(f"{d.card_name}: designed schedule (moment-model prediction{marker_note})", y=1 - 0.2 / H)
    savefig(fig, path, dpi=110)


def write_design(d: Design, out: Path) -> list[Path]:
    """Write schedule.toml, predicted.csv and design.png under ``out`` as one set (:func:`bmctl.io.output_set`:
    all three or none, also on Ctrl-C)."""
    out = Path(out)
    paths = [out / "schedule.toml", out / "predicted.csv", out / "design.png"]
    with output_set():
        write_text(paths[0], schedule_toml(d))
        write_text(paths[1], predicted_csv(d))
        design_figure(d, paths[2])
    return paths
