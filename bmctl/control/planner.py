"""Receding-horizon planning on operable schedules: the MPC with ``[plan] method = "search"``.

At every call the controller plans the whole rest of the batch (the horizon shrinks to the batch
end) with :func:`bmctl.control.search.search`: a vectorised batch of operable schedule families
evaluated on the moment model from the estimate, then a local search on the same operable grid
(rpm dial steps, whole minutes, phase splits, the total milling time). The advice is the plan's
first interval. Because every candidate keeps the dwell limits, the switch budget and the rpm rate
limit over the whole horizon, including the periods already run (:class:`~bmctl.control.search.Carry`),
the first move always belongs to a plan the mill can run: it never rests now while its own plan
needs milling that the limits would then forbid, and nothing is rounded after solving.

The estimator's (gamma, delta) enter every plan, with their spread: the search steers the estimate
(its mean state and gamma, delta) to the target; a pool of the plans that come within
``[plan] pool_band`` of the best is then predicted for ``[plan] spread`` of the filter's particles
(a deterministic weighted selection, :func:`bmctl.control.robust.particle_scenarios`) and scored
``e^2 + risk (Var(e) - Var_rest(e))``, the variance the plan adds to that of resting on: a plan
whose outcome the filter's uncertainty scatters (e.g. over the welding hump and back) loses to a
safer one that is nearly as close. The vial ceiling holds for each particle's temperature while
milling: above it (the vial or one particle), every milling candidate exceeds it and the plan rests.

A re-plan starts from the previous plan shifted to now: when it still comes within the tolerance
(``[objective] tolerance``) of the target, a local search around it (its neighbours on the grid)
decides; otherwise, and at the first call, the global search runs (the previous plan among its
candidates).

The plan is a function of its inputs only -- the estimate, the spread, the mill's record and the
previous plan -- so the same inputs give the same plan.
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..errors import InputError
from .base import Plan, Reference, Status, batch_end_h, check_p, check_u_prev, check_x
from dataclasses import replace

from .search import (CEILING_TOL_C, Carry, Grid, _row, expand, fit_power, limits_of, make_grid, operable, power_bound,
                     search, shift_params, thermal_peaks)


#: ``binding`` names the spread when another family comes this much closer nominally (relative error)
SPREAD_NOTE = 0.005


class PlanController:
    """Plans the rest of the batch on operable schedules; build with :func:`bmctl.control.make_controller`.

    Parameters
    ----------
    cfg : MPCConfig
        ``[plan]`` (search settings), ``[bounds]``, ``[temperature]``, ``[weights]``, ``[mill]``.
    model : MomentModel
    reference : dict, Reference, list or callable, optional
        Target (the batch-end value is planned for).
    """

    kind = "mpc"
    uses_history = True

    def __init__(self, cfg, model, reference=None):
        self.cfg = cfg
        self.model = model
        self.interval_h = float(cfg.interval_h)
        self.N = int(cfg.horizon)
        self.t_end_h = float(cfg.batch_hours if cfg.batch_hours is not None else model.card.process.hours)
        self.reference = Reference.from_config(cfg) if reference is None else Reference.make(reference)
        self.lim = limits_of(cfg, model)
        self.n_scen = 1  # the loop passes particles (spread_particles), not quantile corners
        self.spread_particles = int(cfg.plan.spread)
        self.reset()

    def set_target(self, target, t_end_h: float | None = None) -> None:
        """Set the target (see :meth:`bmctl.control.mpc.MPCController.set_target`) and the batch end."""
        self.reference = Reference.make(target)
        if t_end_h is not None:
            self.t_end_h = batch_end_h(t_end_h)

    def reset(self) -> None:
        """Forget the previous plan and the record of applied intervals."""
        self._prev = None
        self._hist: list[tuple[float, float, float]] = []
        self._last_t: float | None = None

    def get_state(self) -> dict:
        """The previous plan and the applied intervals, as plain data."""
        return {"prev": self._prev, "hist": [list(h) for h in self._hist], "last_t": self._last_t}

    def set_state(self, state: dict) -> None:
        """Restore a state from :meth:`get_state` (a state of another controller kind is ignored)."""
        if not isinstance(state, dict) or "hist" not in state:
            self.reset()
            return
        pr = state.get("prev")
        self._prev = None if pr is None else {"t_h": float(pr["t_h"]), "params": [float(v) for v in pr["params"]],
                                              "minutes": [float(v) for v in pr["minutes"]],
                                              "family": str(pr["family"])}
        self._hist = [tuple(float(v) for v in h) for h in state["hist"]]
        self._last_t = None if state.get("last_t") is None else float(state["last_t"])

    # --- planning --------------------------------------------------------------------------------
    def _record(self, t: float, u_prev) -> None:
        """Append the interval applied since the last call (trials: the controller keeps its own record)."""
        if self._last_t is None or t <= self._last_t + 1e-9:
            if self._last_t is not None and t <= self._last_t - 1e-9:
                self._hist = []
            self._last_t = t
            return
        if u_prev is not None:
            self._hist.append((t - self._last_t, float(u_prev[0]), float(u_prev[1])))
        self._last_t = t

    def target_at_end(self) -> dict:
        return self.reference.at(self.t_end_h)

    def plan(self, x_est, t_h: float, p=None, u_prev=None, scenarios=None, history=None) -> Plan:
        """Plan from ``x_est`` at batch time ``t_h`` to the batch end; the first interval is the advice.

        Parameters
        ----------
        x_est : array_like, (6,)
        t_h : float
        p : array_like, (2,), optional
            (gamma_mult, delta_mult) estimate.
        u_prev : array_like, (2,), optional
            Input applied over the previous interval (the controller's own record of the mill).
        scenarios : list of (x, p), optional
            The spread: filter particles (:func:`bmctl.control.robust.particle_scenarios`) or other
            (x, p) pairs; at most ``[plan] spread`` are used.
        history : list of (hours, rpm, milling[, reading]), optional
            What the mill ran since the batch start (a campaign's log), with the vial reading at the
            end of each interval where one was taken; replaces the own record. The readings fit the
            mill's heating power; the next interval's ceiling is checked at its upper bound
            (:func:`bmctl.control.search.power_bound`, ``[temperature] heating_sd`` and ``heating_z``),
            the later ones, re-planned after the next reading, at the fit: a mill that heats more
            than its card does not overshoot before its readings show it.
        """
        x0 = check_x(x_est)
        pp = check_p(self.model, p)
        up = check_u_prev(u_prev, self.model)
        t = float(t_h)
        if not math.isfinite(t) or t < 0:
            raise InputError(f"t_h: must be a finite number >= 0 (got {t_h})")
        self._record(t, up)
        hist = self._hist if history is None else history
        carry = Carry.from_history(hist)
        loose = replace(carry, check_open=False)  # the open period excepted: the search's first pass (below)
        if history is None:  # the own record carries no readings: the card's heating
            power = power_hi = fit_power(self.model, hist)
        else:  # a mill's log: the heating fitted to its readings, the ceiling checked at its upper bound
            tc = self.cfg.temperature
            power, power_hi = power_bound(self.model, hist, tc.heating_sd, tc.heating_z)
        lim = replace(self.lim, power=power, power_first=power_hi)
        ceil = self.cfg.temperature.ceiling_c
        grid = make_grid(t, self.t_end_h, self.interval_h)
        target = self.target_at_end()
        t0, c0 = time.perf_counter(), time.process_time()
        if grid.K == 0 or not target:
            why = "batch finished: rest" if grid.K == 0 else "no target: rest"
            U = np.zeros((1, 2))
            X = np.vstack([x0, x0])
            st = Status("mpc", "batch_done" if grid.K == 0 else "no_target", True, t_ceiling_c=ceil, reason=why)
            return Plan(t, self.interval_h, U, X, np.array([x0[4]]), np.zeros(2), st,
                        {"binding": [], "family": "rest"})
        x0s, ps = [x0], [pp]
        for xs, pq in list(scenarios or [])[: self.spread_particles]:
            x0s.append(check_x(xs))
            ps.append(check_p(self.model, pq))
        extra = []
        prev = self._prev
        if prev is not None:
            s = (t - prev["t_h"]) / self.interval_h
            if s >= -1e-6 and abs(s - round(s)) < 1e-6:
                q = shift_params(np.array(prev["params"]), np.array(prev["minutes"]), int(round(s)))
                extra.append((q, "previous"))
                r_q, m_q = expand(q[None], grid, self.lim, loose)
                if m_q.sum() > 0:  # the same milling, started now: a local move the phases cannot make
                    on = m_q[0] > 0
                    extra.append((np.array(_row(float(np.max(r_q[0][on])), grid.interval_min, 1, grid.K,
                                                cap=float(m_q.sum()))), "constant"))
        ps_cfg = self.cfg.plan
        has_milled = milled(hist)
        # before the first milling resting is kept out of the pool (rest_within): a nudge there would be a
        # token burst after which resting is let back in, so nudges are weighed once the mill has milled
        sub = ps_cfg.substeps if ps_cfg.onset_substeps is None else (ps_cfg.onset_substeps, ps_cfg.substeps)
        kw = dict(substeps=sub, rpm_step=ps_cfg.rpm_step, band=ps_cfg.error_band,
                  coarse_factor=ps_cfg.coarse_factor, pool=ps_cfg.pool, pool_band=ps_cfg.pool_band, risk=ps_cfg.risk,
                  rest_within=None if has_milled else self.cfg.objective.tolerance,
                  nudge_above=self.cfg.objective.tolerance if ps_cfg.nudge and has_milled else None)

        def searched(c: Carry):
            args = (self.model, np.array(x0s), np.array(ps), target, grid, lim, self.cfg.weights, c)
            if extra:  # the previous plan still reaches the target: a local search around it
                tol = self.cfg.objective.tolerance
                r = search(*args, rounds=0, extra=extra, coarse=False, give_up_above=tol, **kw)
                if r is not None and r.error <= tol:
                    return r, "local"
            return search(*args, rounds=ps_cfg.rounds, extra=extra, **kw), "global"

        # The period open at t (a logged rest or milling period) counts toward the dwell minimums. The
        # search excepts it first and its plan is kept where that plan keeps the minimums with it: checked
        # from the start, the candidates that end the period short drop out of the local search's heads
        # and of the spread's pool and so move decisions that keep it too. Where the plan would end it
        # short (a 1-min logged rest, milling at once), the search runs again with the period checked (a
        # short rest then rests on through the first interval: :meth:`Carry.rests_on`);
        # its plan replaces the first unless it would take the vial over the ceiling where the first did
        # not (a logged milling period shorter than the minimum may then end short: the ceiling first).
        res, scope = searched(loose)
        if not operable(res.minutes[None], grid, lim, carry)[0][0]:
            try:
                kept, kept_scope = searched(carry)
            except RuntimeError:  # nothing keeps it (cannot happen to a logged rest: resting on keeps it)
                kept = None
            if kept is not None and kept.peak_c <= max(res.peak_c, ceil + CEILING_TOL_C):
                res, scope = kept, kept_scope
        ms = (time.perf_counter() - t0) * 1e3
        cpu = (time.process_time() - c0) * 1e3
        fam = res.family if res.family != "previous" else (prev or {}).get("family", "previous")
        self._prev = {"t_h": t, "params": [float(v) for v in res.params], "minutes": [float(v) for v in res.minutes],
                      "family": fam}
        dt_min = self.interval_h * 60.0
        U = np.column_stack([res.rpm, res.minutes / dt_min])
        X = res.X[0]
        X0s = np.array(x0s)
        res.peaks_c = thermal_peaks(self.model, X0s[:, 4], X0s[:, 5], res.rpm[None], res.minutes[None], grid,
                                    lim.power, per_interval=True, power_first=lim.power_first)[:, 0, :]
        peaks = res.peaks_c.max(axis=0)
        binding = plan_binding(res, grid, lim, carry, ceil)
        st = Status("mpc", f"{scope} search", True, res.evaluated, ms, cost=res.rms, t_ceiling_c=ceil,
                    reason=f"{fam}: {describe_plan(res, grid)}")
        st.solve_cpu_ms = cpu
        st.t_peak_max_c = float(res.peak_c)
        u_apply = U[0].copy() if res.minutes[0] > 0 else np.zeros(2)
        extra_out = {"family": fam, "params": [float(v) for v in res.params], "error": res.error, "rms": res.rms,
                     "binding": binding, "per_family": res.per_family, "evaluated": res.evaluated,
                     "nodes": res.nodes, "switches": res.switches, "switches_used": carry.switches, "scope": scope,
                     "power": power, "power_ceiling": power_hi,
                     "lengths_min": grid.lengths_min.tolist(), "minutes": res.minutes.tolist(),
                     "spread_x_end": res.X[1:, -1].copy() if res.X.shape[0] > 1 else None}
        return Plan(t, self.interval_h, U, X, peaks, u_apply, st, extra_out)


def milled(history) -> bool:
    """Whether any logged interval ``(hours, rpm, milling, ...)`` milled.

    Examples
    --------
    >>> milled([(0.5, 0.0, 0.0), (0.5, 300.0, 0.0)]), milled([(0.5, 300.0, 0.5)])
    (False, True)
    """
    return any(float(h[1]) > 0 and float(h[2]) > 0 and float(h[0]) > 0 for h in history)


def describe_plan(res, grid: Grid) -> str:
    """One line: the plan's rpm range, milling time, switches and predicted error at the estimate's mean (the
    spread's median miss, which ``why`` names, can differ)."""
    from .search import describe

    return (f"{describe(res.rpm, res.minutes, grid)}; {res.switches} switches; predicted error "
            f"{100 * res.error:.1f} % at the estimate's mean, peak {res.peak_c:.1f} °C")


def plan_binding(res, grid: Grid, lim, carry: Carry, ceiling_c: float) -> list[str]:
    """The limits the plan runs against (each names where in the plan), for ``advise``'s ``binding``.

    Parameters
    ----------
    res : SearchResult
    grid : Grid
    lim : Limits
    carry : Carry
    ceiling_c : float
    """
    out = []
    on = res.minutes > 0
    t = grid.t0_h + np.concatenate([[0.0], np.cumsum(grid.lengths_min)[:-1]]) / 60.0
    pk = res.peaks_c.max(axis=0) if res.peaks_c is not None and res.peaks_c.size else np.zeros(grid.K)
    hot = np.flatnonzero(pk >= ceiling_c - 0.5)
    others = [r for f, r in (res.per_family or {}).items() if f != "rest"]
    if not on.any() and res.peak_c > ceiling_c + CEILING_TOL_C and others \
            and all(r["peak_c"] > ceiling_c + CEILING_TOL_C for r in others):
        # the vial (in one scenario at least) is at the ceiling now: every plan that mills now is over it,
        # so the plan shown rests to the end; the next advice, from a cooler vial, plans milling again
        # milling again takes a start, and a stop first when the mill is milling now
        need = 1 + (1 if carry is not None and carry.state == 1 else 0)
        used = int(carry.switches) if carry is not None else 0
        if lim.max_switches is not None and used + need > lim.max_switches:
            out.append(f"vial-temperature ceiling ({ceiling_c:g} °C) now: the vial is at it (up to {res.peak_c:.1f} "
                       f"°C in the filter's spread), so no plan may start milling; this one rests, and with "
                       f"{used} of {lim.max_switches} switches used the mill cannot start again this batch")
        else:
            out.append(f"vial-temperature ceiling ({ceiling_c:g} °C) now: the vial is at it (up to {res.peak_c:.1f} "
                       "°C in the filter's spread), so no plan may start milling; this one rests, and the next "
                       "advice, with the vial cooler, plans milling again")
    elif hot.size:
        out.append(f"vial-temperature ceiling ({ceiling_c:g} °C) from {t[hot[0]]:g} h")
    elif getattr(res, "over_ceiling", None):  # the plan stays clear of the ceiling, closer ones do not
        r = res.over_ceiling
        out.append(f"vial-temperature ceiling ({ceiling_c:g} °C): closer schedules run over it ({r['schedule']}: "
                   f"{100 * r['error']:.1f} % off, peak {r['peak_c']:.1f} °C)")
    top = np.flatnonzero(on & (res.rpm >= lim.rpm_hi - 1e-6))
    if top.size:
        out.append(f"rpm at its upper bound ({lim.rpm_hi:g} rpm) from {t[top[0]]:g} h")
    low = np.flatnonzero(on & (res.rpm <= lim.rpm_lo + 1e-6))
    if low.size:
        out.append(f"rpm at its lower bound ({lim.rpm_lo:g} rpm) from {t[low[0]]:g} h")
    if res.at_min_mill and lim.min_mill:
        out.append(f"minimum milling period ({lim.min_mill:g} min)")
    if res.at_min_rest and lim.min_rest:
        out.append(f"minimum rest ({lim.min_rest:g} min)")
    if lim.max_switches is not None and res.switches >= lim.max_switches - 1:
        used = int(carry.switches) if carry is not None else 0  # the plan's count includes the logged ones
        out.append(f"switch budget ({res.switches} of {lim.max_switches} over the batch with this plan"
                   + (f", {used} used so far" if used else "") + ")")
    if on.all() and np.all(res.minutes >= grid.lengths_min - 1e-9) and res.error > 0:
        out.append("batch time: milling throughout to the batch end")
    closer = [(f, r) for f, r in (res.per_family or {}).items()
              if r["error"] < res.error - SPREAD_NOTE and r["peak_c"] <= ceiling_c + CEILING_TOL_C]
    if closer:  # the spread, not a limit: a closer plan's outcome scatters more over the filter's particles
        f, r = min(closer, key=lambda fr: fr[1]["error"])
        out.append(f"the filter's spread: {f} ({r['schedule']}) ends {100 * r['error']:.1f} % off nominally but "
                   f"scatters more over the filter's particles; this plan ends {100 * res.error:.1f} % off")
    return out


def expand_params(cfg, model, params, t_h: float, t_end_h: float, history=None):
    """The (rpm, minutes) per interval of a parameter row on the grid from ``t_h`` (for reports and tests).

    Parameters
    ----------
    cfg : MPCConfig
    model : MomentModel
    params : array_like, (9,)
    t_h, t_end_h : float
    history : list of (hours, rpm, milling), optional
    """
    grid = make_grid(t_h, t_end_h, cfg.interval_h)
    rpm, mins = expand(np.asarray(params, dtype=float)[None], grid, limits_of(cfg, model),
                       Carry.from_history(history or []))
    return rpm[0], mins[0]
