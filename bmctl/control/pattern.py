"""Phase-pattern schedules for ``bmctl design``: a batch of a few phases, each one rpm and one
mill/rest cycle repeated (the paper's 30 min / 10 min interrupted milling is one such phase).

Decisions per phase p (length L = hours / phases): the rpm (in the mill's steps), the duty
f_p (share of each cycle spent milling), the number of cycles k_p and whether the phase is
interrupted (y_p = 1) or continuous (y_p = 0, f_p = 1). Milling a_p = f_p L / k_p and rest
b_p = (1 - f_p) L / k_p per cycle are what the operator sets. Constraints:

* dwell: a_p >= min_mill; b_p >= min_rest when interrupted;
* switches: sum_p 2 y_p k_p <= max_switches;
* vial ceiling: the first cycle's peak (closed form from the phase's start temperature) and
  the periodic peak of the repeated cycle, T1 = [T_ss (1 - A) + A T_amb (1 - B)] / (1 - A B),
  A = exp(-a/tau), B = exp(-b/tau), stay under the ceiling (slack, heavily penalised);
* rpm within [max(rpm_min, rpm_min_milling), rpm_max].

The moments follow the moment model on a grid of <= 0.5 h steps, each step milling the
phase's duty (the cycle averaged). The rounded schedule is then simulated segment by segment
(exact for the model) for every number reported.

Integer decisions (rpm steps, k_p, y_p): ``relax-round`` solves the continuous relaxation
(IPOPT), rounds y, k (within the switch budget) and rpm, and re-solves the duties with the
integers fixed; ``bonmin`` hands the same MINLP to casadi's Bonmin (B-BB). docs/control.md
compares both.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from .config import TARGET_KEYS, target_bounds, target_centre
from .interrupt import keep_interrupts
from .mill import count_switches
from .outputs import ERR_FLOOR, output_dict, output_values, relative_error

GRID_H = 0.5  # longest step of the design's moment grid (h)
STARTS = 3  # start points of the relaxed solve (relax-round)


@dataclass
class PatternResult:
    """A designed phase pattern and its exact (segment-wise) prediction."""

    hours: float
    rpm: np.ndarray  # per phase
    duty: np.ndarray
    cycles: np.ndarray
    interrupted: np.ndarray
    segments: list  # (hours, rpm), rpm 0 = rest
    X_end: np.ndarray
    peak_c: float
    energy_kWh: float
    milling_h: float
    error: float  # largest relative target error (0 inside a window)
    outputs: dict
    solve_s: float
    cost: float
    method: str
    status: str
    slack_c: float = 0.0
    seg_states: list = field(default_factory=list)

    active: list = field(default_factory=list)  # limits active at the solution (see PatternDesigner.active)
    family: str = ""  # the search's schedule family, for a search result (bmctl.control.search)

    @property
    def switches(self) -> int:
        return count_switches(self.segments)


def _design_step(model, dt_h: float, substeps: int):
    """The moment step of the design grid: compiled with its reverse derivative from bmctl's cache
    (compiled in the foreground when missing: about 5 s of gcc, repaid within the first solve), else
    the interpreted SX step. Same equations either way (tests/control/test_mpc_cache.py)."""
    from .compiled import compiled_step

    F = compiled_step(model, dt_h, substeps, reverse=True, wait=True)
    return F if F is not None else model.casadi_step(dt_h, substeps)


class PatternDesigner:
    """Builds and solves the phase-pattern problem for one card, batch length and settings.

    Parameters
    ----------
    model : MomentModel
    hours : float
    cfg : MPCConfig
        Bounds, temperature, weights, mill limits and ``objective.phases``.
    target : dict
        {key: point or (lo, hi)}.
    p : array_like, optional
        (gamma_mult, delta_mult).
    energy_weight : float, optional
        Weight of the milling energy (per kWh) in the objective (default: the controller's
        ``weights.energy_per_kWh``).
    """

    def __init__(self, model, hours: float, cfg, target: dict, p=None, energy_weight: float | None = None):
        self.model, self.cfg, self.target = model, cfg, dict(target)
        self.hours = float(hours)
        self.P = int(cfg.objective.phases)
        self.L = self.hours / self.P
        self.n_sub = max(1, int(math.ceil(self.L / GRID_H - 1e-9)))
        self.p = model.p0() if p is None else np.asarray(p, dtype=float)
        mill = cfg.mill
        self.step = mill.rpm_step or 1.0
        self.rpm_hi = min(cfg.bounds.rpm_max, model.rpm_max)
        self.rpm_lo = min(max(cfg.bounds.rpm_min, mill.rpm_min_milling, self.step), self.rpm_hi)
        self.k_max = max(1, int(math.floor(self.L * 60.0 / max(mill.min_mill_min + mill.min_rest_min, 2.0))))
        self.energy_weight = cfg.weights.energy_per_kWh if energy_weight is None else energy_weight
        self._build()

    # --- the NLP -------------------------------------------------------------------------------
    def _build(self):
        import casadi as ca

        from ..moments import equations as eq

        m, c, cfg, P = self.model, self.model.const, self.cfg, self.P
        mill = cfg.mill
        dtg = self.L / self.n_sub
        F = _design_step(m, dtg, cfg.solver.substeps)  # the MPC's prediction accuracy; reported numbers are re-simulated
        n = ca.MX.sym("n", P)  # rpm / step
        f = ca.MX.sym("f", P)  # duty
        k = ca.MX.sym("k", P)  # cycles
        y = ca.MX.sym("y", P)  # interrupted
        sl = ca.MX.sym("sl", P)  # temperature slack (degC)
        x = ca.DM(m.x0())
        p = ca.DM(self.p)
        g, lbg, ubg = [], [], []
        ceil = cfg.temperature.ceiling_c
        L = self.L
        energy = 0
        for i in range(P):
            rpm = n[i] * self.step
            w = rpm / c.rpm_max
            a_h, b_h = f[i] * L / k[i], (1 - f[i]) * L / k[i]
            T_first, _ = eq.thermal_exact(eq.CA(), c, x[4], x[5], w, a_h)
            T_ss = c.ambient_C + eq.power_W(c, w) * c.cooling_time_h * 3600.0 / c.heat_capacity_J_per_K
            A, B = ca.exp(-a_h / c.cooling_time_h), ca.exp(-b_h / c.cooling_time_h)
            T_per = (T_ss * (1 - A) + A * c.ambient_C * (1 - B)) / (1 - A * B + 1e-9)
            g += [T_first - sl[i], y[i] * (T_per - ceil) - sl[i]]
            lbg += [-np.inf, -np.inf]
            ubg += [ceil, 0.0]
            g += [f[i] * L * 60 - mill.min_mill_min * k[i], (1 - f[i]) * L * 60 - mill.min_rest_min * k[i] * y[i],
                  f[i] + y[i]]
            lbg += [0.0, 0.0, 1.0]
            ubg += [np.inf, np.inf, np.inf]
            for _ in range(self.n_sub):  # moments through the step function; T, h in closed form beside it
                T1, h1 = eq.thermal_exact(eq.CA(), c, x[4], x[5], w, f[i] * dtg)
                T2, h2 = eq.thermal_exact(eq.CA(), c, T1, h1, 0.0, (1 - f[i]) * dtg)
                x = ca.vertcat(F(x, ca.vertcat(rpm, f[i]), p)[:4], T2, h2)
            energy = energy + c.power_max_W * w ** 3 * f[i] * L / 1000.0
        if mill.max_switches is not None:
            g.append(ca.sum1(2 * y * k))
            lbg.append(-np.inf)
            ubg.append(float(mill.max_switches))
        keys = list(self.target)
        Y = output_values(x, keys)
        err = 0
        for key, v in zip(keys, Y):
            lo, hi = target_bounds(self.target[key])
            sc = max(abs(target_centre(self.target[key])), ERR_FLOOR[key])
            e = (ca.fmax(v - hi, 0) + ca.fmin(v - lo, 0)) / sc
            err = err + e * e
        wt, tp = cfg.weights, cfg.temperature
        milling_h = ca.sum1(f) * L
        J = (wt.terminal * err + self.energy_weight * energy + wt.time_per_h * milling_h
             + tp.slack_weight * ca.sum1(sl) + tp.slack_weight_quad * ca.sumsqr(sl)
             + wt.rpm_move * ca.sumsqr(ca.diff(n * self.step / c.rpm_max)))
        V = ca.vertcat(n, f, k, y, sl)
        self.nlp = {"x": V, "f": J, "g": ca.vertcat(*g)}
        self._g = ca.Function("g", [V], [self.nlp["g"]])
        self.lbg, self.ubg = np.array(lbg, float), np.array(ubg, float)
        self._xend = ca.Function("xend", [V], [x])

    def _bounds(self):
        P = self.P
        lbx = np.concatenate([np.full(P, self.rpm_lo / self.step), np.zeros(P), np.ones(P), np.zeros(P), np.zeros(P)])
        ubx = np.concatenate([np.full(P, self.rpm_hi / self.step), np.ones(P), np.full(P, self.k_max),
                              np.full(P, 1.0 if self.k_max >= 1 and self._can_interrupt() else 0.0), np.full(P, np.inf)])
        return lbx, ubx

    def _can_interrupt(self) -> bool:
        mill = self.cfg.mill
        return self.L * 60 >= max(mill.min_mill_min, 1) + max(mill.min_rest_min, 1)

    def _opts(self, it=300):
        return {"print_time": False, "ipopt.print_level": 0, "ipopt.sb": "yes", "ipopt.max_iter": it,
                "ipopt.tol": 1e-6, "ipopt.hessian_approximation": "limited-memory"}

    def start_from(self, rpm, minutes, interval_min: float) -> np.ndarray:
        """A start point of the relaxed solve from an operable schedule on the interval grid (the
        global search's candidates, :mod:`bmctl.control.search`): per phase its milling-weighted rpm,
        its milled share, the milling periods that start in it, interrupted when it rests.

        Parameters
        ----------
        rpm, minutes : ndarray, (K,)
            Per interval: rpm and milling minutes (mill first, then rest).
        interval_min : float
            Interval length (min).
        """
        P, K = self.P, len(minutes)
        t = np.arange(K) * interval_min
        L_min = self.L * 60.0
        n, f, k, y = (np.zeros(P) for _ in range(4))
        on_prev = False
        for i in range(P):
            sel = (t >= i * L_min - 1e-9) & (t < (i + 1) * L_min - 1e-9)
            a, r = np.asarray(minutes)[sel], np.asarray(rpm)[sel]
            tot = float(a.sum())
            n[i] = (float((r * a).sum()) / tot if tot > 0 else self.rpm_lo) / self.step
            f[i] = min(1.0, tot / L_min)
            starts = 0
            for aa, LL in zip(a, np.full(a.size, interval_min)):
                if aa > 0 and not on_prev:
                    starts += 1
                on_prev = aa >= LL - 1e-9 if aa > 0 else False
            k[i] = float(np.clip(max(starts, 1), 1, self.k_max))
            y[i] = 1.0 if f[i] < 0.995 and self._can_interrupt() else 0.0
            if y[i] > 0:
                f[i] = max(f[i], self.cfg.mill.min_mill_min * k[i] / L_min)
        lbx, ubx = self._bounds()
        V = np.concatenate([n, f, k, y, np.zeros(P)])
        return np.clip(V, lbx, ubx)

    def _guess(self, which: int = 0):
        """Start points: the given ones (:meth:`start_from`) first, then 0 the card's rpm, 3/4 duty,
        one cycle; 1 the top rpm in the most short cycles (the cool-burst corner); 2 mid rpm, half duty."""
        P = self.P
        given = getattr(self, "starts", [])
        if which < len(given):
            return np.asarray(given[which], dtype=float)
        which -= len(given)
        if which == 1:
            r0, f0, k0 = self.rpm_hi, 0.25, float(self.k_max)
        elif which == 2:
            r0, f0, k0 = 0.5 * (self.rpm_lo + self.rpm_hi), 0.5, max(1.0, 0.5 * self.k_max)
        else:
            r0, f0, k0 = float(np.clip(self.model.card.process.rpm, self.rpm_lo, self.rpm_hi)), 0.75, 1.0
        return np.concatenate([np.full(P, r0 / self.step), np.full(P, f0), np.full(P, k0), np.full(P, 0.5),
                               np.zeros(P)])

    # --- solves --------------------------------------------------------------------------------
    def solve(self, method: str = "relax-round") -> PatternResult:
        """Solve with ``relax-round`` or ``bonmin``; returns the rounded, simulated pattern."""
        import casadi as ca

        t0 = time.perf_counter()
        lbx, ubx = self._bounds()
        P = self.P
        if method == "bonmin":
            opts = {"print_time": False, "discrete": [True] * P + [False] * P + [True] * (2 * P) + [False] * P,
                    "bonmin.print_level": 0, "bonmin.hessian_approximation": "limited-memory",
                    "bonmin.algorithm": "B-BB", "bonmin.time_limit": 600.0}
            s = ca.nlpsol("design_bonmin", "bonmin", self.nlp, opts)
            with keep_interrupts():
                r = s(x0=self._guess(), lbx=lbx, ubx=ubx, lbg=self.lbg, ubg=self.ubg)
            V = np.asarray(r["x"], float).ravel()
            status = str(s.stats().get("return_status", "?"))
            V[:P] = np.round(V[:P])
            V[2 * P:4 * P] = np.round(V[2 * P:4 * P])
        else:
            starts, s = self._relaxed_starts(lbx, ubx)  # s: a relaxed start's solver, free again
            # round the best relaxed point; where rounding loses the target, the next starts' too
            best = None
            for _, V in sorted(starts, key=lambda e: e[0]):
                Vr = self._round(V)
                lb2, ub2 = lbx.copy(), ubx.copy()
                for sl in (slice(0, P), slice(2 * P, 4 * P)):
                    lb2[sl] = ub2[sl] = Vr[sl]
                with keep_interrupts():
                    r2 = s(x0=Vr, lbx=lb2, ubx=ub2, lbg=self.lbg, ubg=self.ubg)
                res = self._result(np.asarray(r2["x"], float).ravel(), 0.0, method,
                                   str(s.stats().get("return_status", "?")))
                if best is None or res.error < best.error:
                    best = res
                if best.error <= self.cfg.objective.tolerance:
                    break
            best.solve_s = time.perf_counter() - t0
            return best
        return self._result(V, time.perf_counter() - t0, method, status)

    def _relaxed_starts(self, lbx, ubx) -> tuple[list, object]:
        """(cost, x) of the relaxed solve from each start point, and a solver to reuse. The relaxation
        is non-convex (welding hump), so a few starts, run side by side on ``solver.design_threads``
        threads, each start with its own IPOPT solver (one solver's work memory cannot be shared
        between threads; on one thread one solver serves them all): casadi releases the GIL while it
        solves, and the results do not depend on the thread count."""
        import casadi as ca
        from concurrent.futures import ThreadPoolExecutor

        from ..parallel import default_workers

        threads = min(STARTS, self.cfg.solver.design_threads or default_workers())
        solvers = [ca.nlpsol(f"design_relaxed_{w}", "ipopt", self.nlp, self._opts())
                   for w in range(STARTS if threads > 1 else 1)]

        def start(which):
            with keep_interrupts():  # in the main thread (a serial start); elsewhere the main thread sees Ctrl-C
                r = solvers[which % len(solvers)](x0=self._guess(which), lbx=lbx, ubx=ubx, lbg=self.lbg, ubg=self.ubg)
            return float(r["f"]), np.asarray(r["x"], float).ravel()

        if threads == 1:
            return [start(w) for w in range(STARTS)], solvers[0]
        with ThreadPoolExecutor(threads, thread_name_prefix="bmctl-design") as pool:
            return list(pool.map(start, range(STARTS))), solvers[0]

    def _round(self, V):
        P, mill = self.P, self.cfg.mill
        V = V.copy()
        n, f, k, y = V[:P], V[P:2 * P], V[2 * P:3 * P], V[3 * P:4 * P]
        y[:] = np.where((y >= 0.5) & (f < 0.995), 1.0, 0.0)
        k[:] = np.where(y > 0, np.clip(np.round(k), 1, self.k_max), 1.0)
        if mill.max_switches is not None:
            while np.sum(2 * y * k) > mill.max_switches:
                j = int(np.argmax(y * k))
                if k[j] > 1:
                    k[j] -= 1
                else:
                    y[j] = 0.0
        f[:] = np.where(y > 0, f, 1.0)
        n[:] = np.round(n)
        return V

    # --- schedule --------------------------------------------------------------------------------
    def segments(self, V) -> list:
        """(hours, rpm) segments of a rounded solution: whole minutes; dwell limits kept."""
        from .mill import dwell_minutes

        P, mill = self.P, self.cfg.mill
        n, f, k, y = V[:P], V[P:2 * P], V[2 * P:3 * P], V[3 * P:4 * P]
        segs = []
        L_min = self.L * 60.0
        for i in range(P):
            rpm = float(n[i] * self.step)
            if y[i] < 0.5 or f[i] >= 0.999:
                segs.append([L_min, rpm])
                continue
            kk = int(round(k[i]))
            c_min = L_min / kk
            a = dwell_minutes(f[i] * c_min, math.floor(c_min), mill)
            if a <= 0:
                segs.append([L_min, 0.0])
                continue
            b = c_min - a
            for _ in range(kk):
                segs += [[a, rpm], [b, 0.0]]
        out = []
        for mnt, r in segs:  # merge equal neighbours
            if mnt <= 1e-9:
                continue
            if out and abs(out[-1][1] - r) < 1e-9:
                out[-1][0] += mnt
            else:
                out.append([mnt, r])
        while len(out) > 1 and out[-1][1] == 0.0:  # a trailing rest does nothing to the powder
            out.pop()
        return [(mnt / 60.0, r) for mnt, r in out]

    def simulate(self, segs):
        """Exact model prediction of a schedule: (final state, peak T, energy kWh, milling h, states at segment ends)."""
        from .design import simulate_segments

        return simulate_segments(self.model, segs, self.p)

    def active(self, V, tol_c: float = 0.5, tol_min: float = 0.5) -> list[str]:
        """Limits active at a solution: temperature ceiling, rpm max, minimum milling period, minimum rest,
        switch budget, batch time (every phase milling throughout)."""
        P, mill = self.P, self.cfg.mill
        g = np.asarray(self._g(V), float).ravel()
        ceil = self.cfg.temperature.ceiling_c
        out = []
        rows = g[:5 * P].reshape(P, 5)
        inter = V[3 * P:4 * P] > 0.5
        if np.any(rows[:, 0] >= ceil - tol_c) or np.any(inter & (rows[:, 1] >= -tol_c)):
            out.append("temperature ceiling")
        if np.any(V[:P] * self.step >= self.rpm_hi - 1e-6):
            out.append("rpm max")
        y = V[3 * P:4 * P] > 0.5
        if mill.min_mill_min and np.any(rows[:, 2] <= tol_min):
            out.append(f"minimum milling period ({mill.min_mill_min:g} min)")
        if mill.min_rest_min and np.any(y & (rows[:, 3] <= tol_min)):
            out.append(f"minimum rest ({mill.min_rest_min:g} min)")
        if mill.max_switches is not None and g[5 * P] >= mill.max_switches - 1:
            out.append(f"switch budget ({mill.max_switches})")
        if np.all(V[P:2 * P] >= 0.99):
            out.append("batch time")
        return out

    def _result(self, V, solve_s, method, status) -> PatternResult:
        P = self.P
        segs = self.segments(V)
        x, peak, energy, mh, states = self.simulate(segs)
        outs = output_dict(x)
        err = max((relative_error(outs[kk], v) for kk, v in self.target.items()), default=0.0)
        cost = float(np.asarray(__import__("casadi").Function("J", [self.nlp["x"]], [self.nlp["f"]])(V)).ravel()[0])
        return PatternResult(self.hours, V[:P] * self.step, V[P:2 * P].copy(), V[2 * P:3 * P].copy(),
                             V[3 * P:4 * P].copy(), segs, x, peak, energy, mh, err, outs, solve_s, cost, method,
                             status, float(np.max(V[4 * P:], initial=0.0)), states, self.active(V))
