"""Nonlinear MPC on the moment model: multiple shooting, IPOPT (casadi.nlpsol).

Decisions per control interval k = 0..N-1 (length ``interval_h``):

* ``w_k = rpm_k / rpm_max(model)`` -- the rpm setpoint,
* ``m_k`` in [milling_min, milling_max] -- the share of the interval spent milling (the rest
  of the interval is a rest; the applied share is rounded to whole minutes),
* ``z_k`` -- the scaled state at the end of interval k (multiple shooting),
* ``s_k >= 0`` -- the temperature slack (degC).

Constraints: ``x_{k+1} = F(x_k, u_k, p)`` (the model's step, ``MomentModel.casadi_step``);
``|rpm_k - rpm_{k-1}| <= rpm_step_max`` (and from the last applied rpm, as bounds on rpm_0);
``T_peak,k - s_k <= ceiling`` where T_peak,k is the vial temperature at the end of the
milling phase of interval k (closed form); inputs within bounds; no milling after the
batch end. Cost: relative target errors (stage + terminal), energy, milling time, rpm moves
and the slack (L1 + quadratic). docs/control.md has the details and the numbers.
"""

from __future__ import annotations

import hashlib
import json
import math
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from .base import (Plan, Reference, Status, batch_end_h, applied_input_guarded, check_gamma_delta, check_u_prev,
                   check_rpm_range, check_x, interval_peaks, max_milling_for_ceiling, peak_temperature, rpm_window)
from .config import DVALUE_KEYS, TARGET_KEYS, MPCConfig, target_bounds, target_centre
from .compiled import CompiledSolvers
from .interrupt import keep_interrupts
from .mill import MillGuard
from .outputs import ERR_FLOOR, output_values

#: IPOPT outcomes whose iterate is used; anything else triggers the fallback
ACCEPTED = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
#: state scaling of the shooting variables (s_mean, s_std um; r_mean, r_std; T degC; h)
X_SCALE = np.array([50.0, 30.0, 0.1, 0.1, 100.0, 1.0])
#: number of target quantities (moments, then D-values) carried per interval in the NLP's parameters
NY = len(TARGET_KEYS)
#: built NLPs and interpreted solvers kept per thread, keyed by what they are built from (most recent last)
_BUILT = threading.local()
BUILT_KEEP = 4


def _built_entry(key: str) -> dict:
    """This thread's store for the NLP ``key`` (LRU of :data:`BUILT_KEEP` entries).

    A controller with the same model constants, coefficients and configuration builds the same
    NLP and the same IPOPT solvers; building them (expanding the constraint Jacobian) costs
    seconds, so later controllers in the process (trials one after another, a resumed trial,
    tests) reuse them. Solvers carry no state between calls: warm starts come from the inputs."""
    store = getattr(_BUILT, "store", None)
    if store is None:
        store = _BUILT.store = OrderedDict()
    if key not in store:
        store[key] = {"solvers": {}}
        while len(store) > BUILT_KEEP:
            store.popitem(last=False)
    store.move_to_end(key)
    return store[key]


@dataclass
class _Solution:
    t_h: float
    W: np.ndarray
    M: np.ndarray
    lam_x: np.ndarray
    lam_g: np.ndarray


class MPCController(CompiledSolvers):
    """Receding-horizon MPC on the moment model. Build with :func:`bmctl.control.make_controller`.

    Parameters
    ----------
    cfg : MPCConfig
    model : MomentModel
    reference : dict, Reference, list or callable, optional
        Target (overrides the config's ``target``/``reference``); see :meth:`set_target`.
    """

    kind = "mpc"

    def __init__(self, cfg: MPCConfig, model, reference=None):
        self.cfg = cfg
        self.model = model
        self.interval_h = float(cfg.interval_h)
        self.N = int(cfg.horizon)
        self.t_end_h = float(cfg.batch_hours if cfg.batch_hours is not None else model.card.process.hours)
        self.reference = Reference.from_config(cfg) if reference is None else Reference.make(reference)
        self.rpm_scale = float(model.const.rpm_max)  # w = rpm / rpm_scale inside the NLP
        check_rpm_range(cfg, model.rpm_max)  # no speed left to mill at: refused, not clipped onto each other
        self.rpm_hi = min(cfg.bounds.rpm_max, model.rpm_max)
        self.rpm_lo = min(max(cfg.bounds.rpm_min, cfg.mill.rpm_min_milling), self.rpm_hi)
        self.guard = MillGuard(cfg.mill, self.interval_h)
        self.n_scen = cfg.robust.scenarios if cfg.robust.mode == "scenario" else 1
        self._scen = None  # extra scenarios [(x0, p), ...] of the current call
        self._solvers: dict[str, object] = {}
        self._prev: _Solution | None = None
        self._sticky_exact = False
        self._nlp = None
        self._built: dict = {"solvers": {}}  # this NLP's entry in the thread's store (_built_entry)
        self._nlp_c = None  # the NLP with the rate field as a called function (compiled solvers)
        self._pending: dict = {}  # solver key -> (library path, options) while gcc runs
        self._step_fn = None  # the interval step of the initial guess (compiled when in the cache)
        self.adaptive = cfg.adaptation.mode != "none"
        self.gain = np.ones(4)  # prediction gain per particle moment (Adaptation, mode "gain")
        self.bias = np.zeros(4)  # additive prediction bias per interval (Adaptation, mode "bias")
        self._rls = np.zeros((2, 4))  # forgetting sums: observed x predicted, predicted^2 (relative)
        self._last = None  # (t, x_est, p) of the previous call, for the gain update
        self._nv, self._ng, self._np = self._sizes()

    # --- public ------------------------------------------------------------------------------
    def set_target(self, target, t_end_h: float | None = None) -> None:
        """Set the target: a dict {moment: value} (constant), a list of (from_h, dict)
        (piecewise constant, time-varying), a callable t_h -> dict, or a Reference.
        ``t_end_h`` moves the batch end (the terminal cost and the last milling interval)."""
        ref = Reference.make(target)
        if self._dvalues(ref) != self._dvalues(self.reference):  # D-values enter the NLP: rebuild it
            self._nlp = self._nlp_c = None
            self._solvers, self._pending, self._prev = {}, {}, None
        self.reference = ref
        if t_end_h is not None:
            self.t_end_h = batch_end_h(t_end_h)

    @staticmethod
    def _dvalues(ref) -> bool:
        return any(k in DVALUE_KEYS for k in ref.keys())

    def reset(self) -> None:
        """Forget the previous plan (no warm start, no shifted fallback); Gauss-Newton is tried again."""
        self._prev = None
        self._sticky_exact = False
        self.guard.reset()

    def get_state(self) -> dict:
        """Warm-start and adaptation data as plain data (the solvers are rebuilt from the config)."""
        prev = None if self._prev is None else {
            "t_h": self._prev.t_h, "W": self._prev.W, "M": self._prev.M, "lam_x": self._prev.lam_x,
            "lam_g": self._prev.lam_g}
        last = None if self._last is None else {"t_h": self._last[0], "x": self._last[1], "p": self._last[2]}
        return {"prev": prev, "sticky_exact": self._sticky_exact, "gain": self.gain, "bias": self.bias,
                "rls": self._rls, "last": last, "guard": self.guard.get_state()}

    def set_state(self, state: dict) -> None:
        """Restore a state from :meth:`get_state`."""
        pr = state["prev"]
        self._prev = None if pr is None else _Solution(float(pr["t_h"]), *(np.asarray(pr[k], dtype=float)
                                                                          for k in ("W", "M", "lam_x", "lam_g")))
        self._sticky_exact = bool(state["sticky_exact"])
        self.gain = np.asarray(state["gain"], dtype=float)
        self.bias = np.asarray(state["bias"], dtype=float)
        self._rls = np.asarray(state["rls"], dtype=float)
        if "guard" in state:
            self.guard.set_state(state["guard"])
        la = state["last"]
        self._last = None if la is None else (float(la["t_h"]), np.asarray(la["x"], dtype=float),
                                              np.asarray(la["p"], dtype=float))

    def plan(self, x_est, t_h: float, p=None, u_prev=None, scenarios=None) -> Plan:
        """Solve the MPC problem from ``x_est`` at batch time ``t_h``; see :mod:`bmctl.control.base`.

        ``scenarios`` (scenario MPC, ``[robust] mode = "scenario"``): further (x, p) pairs the plan must
        also serve, e.g. :func:`bmctl.control.robust.filter_scenarios`; default: copies of (x_est, p)."""
        x0 = check_x(x_est)
        pp = check_gamma_delta(self.model, p)
        if self.n_scen > 1:
            sc = list(scenarios or [])[: self.n_scen - 1]
            sc += [(x0, pp)] * (self.n_scen - 1 - len(sc))
            self._scen = [(check_x(a), check_gamma_delta(self.model, b)) for a, b in sc]
        up = check_u_prev(u_prev, self.model)
        t = float(t_h)
        if not math.isfinite(t) or t < 0:
            raise InputError(f"t_h: must be a finite number >= 0 (got {t_h})")
        if self.adaptive:
            self._update_adaptation(x0, t, pp, up)
        if t >= self.t_end_h - 1e-9:
            return self._fixed_plan(x0, t, pp, np.zeros((1, 2)), Status(
                "mpc", "batch_done", True, reason="batch finished: rest", t_ceiling_c=self.cfg.temperature.ceiling_c))
        data = self._problem_data(x0, t, pp, up)
        warm = self._can_warm(t)
        s = self.cfg.solver
        hessian = "exact" if warm and self._sticky_exact else None
        self._solver(warm, hessian)  # built on first use (seconds), outside the timed solve
        t0, c0 = time.perf_counter(), time.process_time()
        res = self._solve(data, warm=warm, hessian=hessian)
        ms = (time.perf_counter() - t0) * 1e3
        if not res["ok"] and warm and hessian is None and s.retry_exact and s.hessian != "exact" and s.max_iter > 0:
            self._sticky_exact = True  # Gauss-Newton failed (large residuals): exact Hessian from now on
            self._solver(True, "exact")
            t1 = time.perf_counter()
            first = res
            res = self._solve(data, warm=True, hessian="exact")
            res["iter"] += first["iter"]
            res["retried"] = first["status"]
            ms += (time.perf_counter() - t1) * 1e3
        cpu_ms = (time.process_time() - c0) * 1e3
        if not res["ok"]:
            plan = self._fallback(x0, t, pp, up, data, res, ms)
            plan.status.solve_cpu_ms = cpu_ms
            return plan
        W, M = res["W"], res["M"]
        status = Status("mpc", res["status"], True, res["iter"], ms, cost=res["f"],
                        slack_max_c=float(np.max(res["S"], initial=0.0)),
                        t_ceiling_c=self.cfg.temperature.ceiling_c)
        status.solve_cpu_ms = cpu_ms
        if "retried" in res:
            status.reason = (f"warm {self.cfg.solver.hessian} solve: {res['retried']}; retried with the exact Hessian"
                             " (kept until reset)")
        if self.guard.active():
            res, extra_ms, note = self._dwell_round(data, res)
            W, M = res["W"], res["M"]
            status.solve_ms += extra_ms
            if note:
                status.reason = (status.reason + "; " if status.reason else "") + note
        self._prev = _Solution(t, W, M, res["lam_x"], res["lam_g"])
        binary = self.cfg.onoff.mode == "binary"
        if binary:
            W, M, extra_ms, loss, note = self._binary(data, res)
            status.solve_ms += extra_ms
            status.binary_loss = loss
            if note:
                status.reason = note
        U = np.column_stack([W * self.rpm_scale, M])
        X = self.model.simulate(x0, U, self.interval_h, pp) if binary else self._states(x0, res["Z"])
        return self._make_plan(x0, t, U, X, status)

    def _step(self, x, u, pp) -> np.ndarray:
        """One interval of the NLP's (uncorrected) prediction with ``[solver] substeps``: the compiled
        step from bmctl's cache (:func:`bmctl.control.compiled.compiled_step`; the same equations,
        nothing built symbolically in a process that finds it), else the casadi step."""
        if self._step_fn is None:
            from .compiled import compiled_step, step_function

            # interpreted, the library's own graph: same bits as the compiled step (the initial guess,
            # and so the plan, must not depend on whether gcc has finished)
            self._step_fn = (compiled_step(self.model, self.interval_h, self.cfg.solver.substeps)
                             or step_function(self.model, self.interval_h, self.cfg.solver.substeps))
        return np.asarray(self._step_fn(x, u, pp), dtype=float).ravel()

    def _predict(self, x0, U, pp) -> np.ndarray:
        """States under ``U`` as the NLP predicts them (with the adaptation's correction when on):
        a dynamically consistent initial guess."""
        mode = self.cfg.adaptation.mode
        X = [np.asarray(x0, dtype=float)]
        for u in U:
            x = X[-1]
            xn = self._step(x, u, pp)
            if mode == "bias":
                xn[:4] += self.bias
            elif mode == "gain":
                xn[:4] = x[:4] + self.gain * (xn[:4] - x[:4])
            X.append(xn)
        return np.array(X)

    def _update_adaptation(self, x0, t, pp, up) -> None:
        """Update the prediction correction from the last interval's discrepancy (Adaptation)."""
        a = self.cfg.adaptation
        last, self._last = self._last, (t, x0.copy(), pp.copy())
        if last is None or up is None or abs(t - (last[0] + self.interval_h)) > 1e-6:
            return
        _, x_prev, p_prev = last
        x_pred = self._step(x_prev, up, p_prev)[:4]
        if a.mode == "bias":
            self.bias = a.forgetting * self.bias + (1.0 - a.forgetting) * (x0[:4] - x_pred)
            return
        ref = np.maximum(np.abs(x_prev[:4]), 1e-6)
        pred = (x_pred - x_prev[:4]) / ref
        obs = (x0[:4] - x_prev[:4]) / ref
        self._rls = a.forgetting * self._rls + np.array([obs * pred, pred * pred])
        w0 = a.prior_rel_change ** 2
        self.gain = np.clip((self._rls[0] + w0) / (self._rls[1] + w0), a.gain_min, a.gain_max)

    # --- problem data ------------------------------------------------------------------------
    def _problem_data(self, x0, t, pp, up) -> dict:
        cfg, N, dt = self.cfg, self.N, self.interval_h
        tk = t + dt * np.arange(N)
        frac = np.clip((self.t_end_h - tk) / dt, 0.0, 1.0)
        frac[frac < 1e-9] = 0.0
        m_ub = np.minimum(cfg.bounds.milling_max, frac)
        m_lb = np.minimum(cfg.bounds.milling_min, m_ub)
        k_end = int(min(N, math.ceil((self.t_end_h - t) / dt - 1e-9)))
        ref_lo = np.zeros((NY, N))
        ref_hi = np.zeros((NY, N))
        q = np.zeros((NY, N))
        wts = cfg.weights
        for k in range(N):
            if k + 1 > k_end:
                break
            tt = min(tk[k] + dt, self.t_end_h)
            d = self.reference.at(tt)
            for i, key in enumerate(TARGET_KEYS):
                if key in d:
                    sc = max(abs(target_centre(d[key])), ERR_FLOOR[key])
                    ref_lo[i, k], ref_hi[i, k] = target_bounds(d[key])
                    wk = getattr(wts, key, 1.0)
                    q[i, k] += wts.stage * dt * wk / sc**2
                    if k + 1 == k_end:
                        q[i, k] += wts.terminal * wk / sc**2
        lo, hi, _ = rpm_window(cfg.bounds, self.model.rpm_max, up)
        has_prev = up is not None and up[0] > 0 and up[1] > 0
        P = np.concatenate([x0, pp, ref_lo.T.ravel(), ref_hi.T.ravel(), q.T.ravel(),
                            [up[0] / self.rpm_scale if has_prev else 0.0, 1.0 if has_prev else 0.0]]
                           + ([self.bias if self.cfg.adaptation.mode == "bias" else self.gain]
                              if self.adaptive else [])
                           + [np.concatenate([a, b]) for a, b in (self._scen or [])[: self.n_scen - 1]])
        sc = self.rpm_scale
        w_lb = np.full(N, self.rpm_lo / sc)
        w_ub = np.full(N, self.rpm_hi / sc)
        w_lb[0], w_ub[0] = lo / sc, hi / sc
        smax = np.inf if cfg.temperature.slack_max_c is None else cfg.temperature.slack_max_c
        ne = self.n_scen - 1
        lbx = np.concatenate([w_lb, m_lb, np.full(6 * N, -np.inf), np.zeros(N), np.full(6 * N * ne, -np.inf)])
        ubx = np.concatenate([w_ub, m_ub, np.full(6 * N, np.inf), np.full(N, smax), np.full(6 * N * ne, np.inf)])
        step = np.inf if cfg.bounds.rpm_step_max is None else cfg.bounds.rpm_step_max / sc
        ceil = cfg.temperature.ceiling_c
        lbg = np.concatenate([np.zeros(6 * N), np.full(N - 1, -step), np.full(N, -np.inf),
                              np.tile(np.concatenate([np.zeros(6 * N), np.full(N, -np.inf)]), ne)])
        ubg = np.concatenate([np.zeros(6 * N), np.full(N - 1, step), np.full(N, ceil),
                              np.tile(np.concatenate([np.zeros(6 * N), np.full(N, ceil)]), ne)])
        return {"x0": x0, "p": pp, "up": up, "t": t, "P": P, "lbx": lbx, "ubx": ubx, "lbg": lbg, "ubg": ubg,
                "w_lo": lo, "w_hi": hi, "m_ub": m_ub, "m_lb": m_lb, "k_end": k_end}

    # --- NLP ---------------------------------------------------------------------------------
    def _build_key(self) -> str:
        """What the NLP is built from: model constants and coefficients, configuration, D-value rows
        (everything else the NLP uses is derived from these)."""
        h = hashlib.sha256(repr(self.model.const).encode())
        h.update(json.dumps(self.model.coeffs, sort_keys=True).encode())
        h.update(self.cfg.model_dump_json().encode())
        h.update(repr(self._dvalues(self.reference)).encode())
        return h.hexdigest()

    def _sizes(self) -> tuple[int, int, int]:
        """Decision, constraint and parameter counts of the NLP (:meth:`_nlp_dict`'s layout), without building it."""
        N, ne = self.N, self.n_scen - 1
        na = 4 if self.adaptive else 0
        nv = 9 * N + 6 * N * ne  # w, m, z (6 per interval), s; z of each further scenario
        ng = 6 * N + (N - 1) + N + 7 * N * ne  # defects, rpm moves, temperature rows; per further scenario
        return nv, ng, 8 + 3 * NY * N + 2 + na + 8 * ne

    def _build(self):
        built = _built_entry(self._build_key())
        if "nlp" not in built:
            nlp = self._nlp_dict(self.model.casadi_step(self.interval_h, self.cfg.solver.substeps))
            built.update(nlp=nlp, J=self._J, nv=self._nv, ng=self._ng, hess=self._hess)
        self._nlp, self._J, self._hess = built["nlp"], built["J"], built["hess"]
        self._nv, self._ng = built["nv"], built["ng"]
        self._built = built

    def _nlp_dict(self, F, keep: bool = True) -> dict:
        """The NLP ``{x, p, f, g}`` with ``F`` as the interval step (``keep``: also the cost function,
        sizes and Gauss-Newton Hessian on ``self``)."""
        import casadi as ca

        from ..moments import equations as eq

        cfg, N, dt, m = self.cfg, self.N, self.interval_h, self.model
        c = m.const
        W = ca.MX.sym("w", N)
        M = ca.MX.sym("m", N)
        Z = ca.MX.sym("z", 6, N)
        S = ca.MX.sym("s", N)
        ne = self.n_scen - 1
        na = 4 if self.adaptive else 0
        o = 8 + 3 * NY * N  # offset of w_prev
        P = ca.MX.sym("P", o + 2 + na + 8 * ne)
        x0, pp = P[0:6], P[6:8]
        lo = ca.reshape(P[8:8 + NY * N], NY, N)
        hi = ca.reshape(P[8 + NY * N:8 + 2 * NY * N], NY, N)
        q = ca.reshape(P[8 + 2 * NY * N:o], NY, N)
        w_prev, has_prev = P[o], P[o + 1]
        D = ca.DM(X_SCALE)
        U = ca.vertcat(W.T * self.rpm_scale, M.T)
        Fm = F.map(N)
        keys = [k for k in TARGET_KEYS if k not in DVALUE_KEYS or self._dvalues(self.reference)]
        rows = [TARGET_KEYS.index(k) for k in keys]

        def predict(Zs, xs0, ps):
            """Scaled shooting states -> (states, defects, peak T per interval, tracking cost)."""
            X = ca.repmat(D, 1, N) * Zs
            Xprev = ca.horzcat(xs0, X[:, :-1])
            Xn = Fm(Xprev, U, ca.repmat(ps, 1, N))
            if self.adaptive and cfg.adaptation.mode == "gain":  # corrected particle moments (T, h are exact)
                G = ca.vertcat(P[o + 2:o + 6], 1.0, 1.0)
                Xn = Xprev + ca.repmat(G, 1, N) * (Xn - Xprev)
            elif self.adaptive:  # "bias": offset-free prediction
                Xn = Xn + ca.repmat(ca.vertcat(P[o + 2:o + 6], 0.0, 0.0), 1, N)
            defect = (Xn - X) / ca.repmat(D, 1, N)
            Tpk, _ = eq.thermal_exact(eq.CA(), c, Xprev[4, :], Xprev[5, :], W.T, M.T * dt)
            Y = ca.vertcat(*output_values(X, keys))
            Lo, Hi, Q = (ca.vertcat(*[A[i, :] for i in rows]) for A in (lo, hi, q))
            # squared distance outside the window [lo, hi] (a point: lo = hi); C1-smooth
            E = ca.fmax(Y - Hi, 0) + ca.fmin(Y - Lo, 0)
            return defect, Tpk, ca.sum1(ca.sum2(Q * E * E))

        defect, Tpk, J_track = predict(Z, x0, pp)
        Zx = [ca.MX.sym(f"z{j + 1}", 6, N) for j in range(ne)]
        extra_g = []
        for j, Zj in enumerate(Zx):
            b = o + 2 + na + 8 * j
            dj, Tj, Jj = predict(Zj, P[b:b + 6], P[b + 6:b + 8])
            J_track = J_track + Jj
            extra_g += [ca.vec(dj), Tj.T - S]
        J_track = J_track / (ne + 1)
        wt = cfg.weights
        J_energy = wt.energy_per_kWh * c.power_max_W / 1000.0 * dt * ca.sum1(W * W * W * M)
        J_time = wt.time_per_h * dt * ca.sum1(M)
        J_move = wt.rpm_move * (has_prev * (W[0] - w_prev) ** 2 + ca.sumsqr(ca.diff(W)))
        J_slack = cfg.temperature.slack_weight * ca.sum1(S) + cfg.temperature.slack_weight_quad * ca.sumsqr(S)
        J = J_track + J_energy + J_time + J_move + J_slack
        gT = Tpk.T - S
        g = ca.vertcat(ca.vec(defect), ca.diff(W), gT, *extra_g)
        V = ca.vertcat(W, M, ca.vec(Z), S, *[ca.vec(Zj) for Zj in Zx])
        nlp = {"x": V, "p": P, "f": J, "g": g}
        if not keep:
            return nlp
        self._J = ca.Function("J", [V, P], [J])
        assert (V.shape[0], g.shape[0], P.shape[0]) == (self._nv, self._ng, self._np)  # _sizes() mirrors this layout
        # Gauss-Newton Hessian of the Lagrangian: the cost's and the temperature rows' curvature, the
        # dynamics' curvature dropped, plus a proximal term on the scaled inputs (cheap to build)
        lf = ca.MX.sym("lam_f")
        lg = ca.MX.sym("lam_g", g.shape[0])
        H = ca.hessian(lf * J + ca.dot(lg[7 * N - 1:8 * N - 1], gT), V)[0]
        reg = np.zeros(V.shape[0])
        reg[:2 * N] = cfg.solver.gn_regularization
        H = H + lf * ca.diag(ca.DM(reg))
        self._hess = ca.Function("nlp_hess_l", {"x": V, "p": P, "lam_f": lf, "lam_g": lg,
                                                "triu_hess_gamma_x_x": ca.triu(H)},
                                 ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"])
        return nlp

    def _solver(self, warm: bool, hessian: str | None = None):
        import casadi as ca

        s = self.cfg.solver
        if hessian is None:
            hessian = s.hessian if warm else s.cold_hessian
        key = ("warm" if warm else "cold", hessian)
        if key not in self._solvers:
            max_iter = s.max_iter
            if warm and hessian == "gauss-newton" and s.retry_exact:
                max_iter = min(max_iter, s.gn_max_iter)
            opts = {"print_time": False, "calc_lam_p": False, "error_on_fail": False,
                    "ipopt.print_level": s.print_level, "ipopt.sb": "yes", "ipopt.max_iter": max_iter,
                    "ipopt.tol": s.tol, "ipopt.acceptable_tol": s.acceptable_tol,
                    "ipopt.acceptable_iter": s.acceptable_iter}
            from . import cache

            # with compiled solvers on, the interpreted solver (used until gcc is done) solves the
            # library's NLP as it is, unexpanded: it then gives the compiled solver's iterates to the
            # last bit, and a run's plans do not depend on the cache (tests/control/test_mpc_cache.py)
            same_as_library = cache.enabled()
            if not same_as_library and (s.expand == "all" or (s.expand == "warm" and warm and hessian != "exact")):
                opts["expand"] = True
            if s.max_wall_s is not None:
                opts["ipopt.max_wall_time"] = s.max_wall_s
            if hessian == "limited-memory":
                opts["ipopt.hessian_approximation"] = "limited-memory"
            if warm:
                opts.update({"ipopt.warm_start_init_point": "yes", "ipopt.warm_start_bound_push": 1e-6,
                             "ipopt.warm_start_slack_bound_push": 1e-6, "ipopt.warm_start_mult_bound_push": 1e-6,
                             "ipopt.mu_init": 1e-4})
            # a compiled library found in the cache is loaded without building the NLP symbolically
            compiled = self._compiled_solver(key, opts) if hessian != "exact" or s.compile_exact else None
            if compiled is None:
                if self._nlp is None:
                    self._build()
                if hessian == "gauss-newton":
                    opts["hess_lag"] = self._hess
                okey = (key, same_as_library, repr(sorted((k, v) for k, v in opts.items() if k != "hess_lag")))
                compiled = self._built["solvers"].get(okey)
                if compiled is None:
                    nlp = self._called_nlp() if same_as_library else self._nlp
                    compiled = self._built["solvers"][okey] = ca.nlpsol(f"mpc_{key[0]}", "ipopt", nlp, opts)
            self._solvers[key] = compiled
        elif key in self._pending:  # a background compile may have finished: switch to it
            self._upgrade(key)
        return self._solvers[key]

    def _can_warm(self, t: float) -> bool:
        if not self.cfg.solver.warm_start or self._prev is None:
            return False
        s = (t - self._prev.t_h) / self.interval_h
        return -1e-6 <= s < self.N - 1e-6 and abs(s - round(s)) < 1e-6

    def _guess(self, data: dict, warm: bool, W=None, M=None):
        """Initial decision vector (dynamically consistent: states simulated) and multipliers."""
        N = self.N
        lam_x = np.zeros(self._nv)
        lam_g = np.zeros(self._ng)
        if W is None and warm:
            s = int(round((data["t"] - self._prev.t_h) / self.interval_h))
            W = _shift(self._prev.W, s)
            M = _shift(self._prev.M, s)
            ne = self.n_scen - 1
            lam_x = np.concatenate([_shift(self._prev.lam_x[:N], s), _shift(self._prev.lam_x[N:2 * N], s),
                                    _shift(self._prev.lam_x[2 * N:8 * N], s, 6),
                                    _shift(self._prev.lam_x[8 * N:9 * N], s), np.zeros(6 * N * ne)])
            lam_g = np.concatenate([_shift(self._prev.lam_g[:6 * N], s, 6),
                                    _shift(self._prev.lam_g[6 * N:7 * N - 1], s),
                                    _shift(self._prev.lam_g[7 * N - 1:8 * N - 1], s), np.zeros(7 * N * ne)])
        elif W is None:
            up = data["up"]
            r0 = up[0] if up is not None and up[0] > 0 else self.model.card.process.rpm
            W = np.full(N, r0 / self.rpm_scale)
            M = np.full(N, 1.0)
        W = np.clip(W, data["lbx"][:N], data["ubx"][:N]).copy()
        if self.cfg.bounds.rpm_step_max is not None:  # make the guess rate-feasible
            st = self.cfg.bounds.rpm_step_max / self.rpm_scale
            for k in range(1, N):
                W[k] = np.clip(W[k], W[k - 1] - st, W[k - 1] + st)
            W = np.clip(W, data["lbx"][:N], data["ubx"][:N])
        M = np.clip(M, data["lbx"][N:2 * N], data["ubx"][N:2 * N])
        U = np.column_stack([W * self.rpm_scale, M])
        X = self._predict(data["x0"], U, data["p"])
        Tpk = peak_temperature(self.model, X[:-1, 4], X[:-1, 5], U[:, 0], U[:, 1], self.interval_h)
        extra = []
        for xs, ps in (self._scen or [])[: self.n_scen - 1]:
            Xs = self._predict(xs, U, ps)
            extra.append((Xs[1:] / X_SCALE).ravel())
            Tpk = np.maximum(Tpk, peak_temperature(self.model, Xs[:-1, 4], Xs[:-1, 5], U[:, 0], U[:, 1],
                                                   self.interval_h))
        S = np.clip(Tpk - self.cfg.temperature.ceiling_c, 0.0, data["ubx"][8 * N:9 * N])
        V = np.concatenate([W, M, (X[1:] / X_SCALE).ravel(), S] + extra)
        return V, lam_x, lam_g

    def _solve(self, data: dict, warm: bool, W=None, M=None, lbx=None, ubx=None, hessian=None) -> dict:
        solver = self._solver(warm, hessian)
        V0, lam_x, lam_g = self._guess(data, warm and W is None, W, M)
        kw = dict(x0=V0, p=data["P"], lbx=data["lbx"] if lbx is None else lbx, ubx=data["ubx"] if ubx is None else ubx,
                  lbg=data["lbg"], ubg=data["ubg"])
        if warm:
            kw.update(lam_x0=lam_x, lam_g0=lam_g)
        with keep_interrupts():  # CasADi swallows Ctrl-C into a failed solve
            sol = solver(**kw)
        st = solver.stats()
        V = np.asarray(sol["x"], dtype=float).ravel()
        N = self.N
        status = str(st.get("return_status", "unknown"))
        ok = status in ACCEPTED and np.all(np.isfinite(V))
        return {"ok": bool(ok), "status": status, "iter": int(st.get("iter_count", 0)), "V": V,
                "f": float(sol["f"]), "W": V[:N].copy(), "M": V[N:2 * N].copy(),
                "Z": V[2 * N:8 * N].reshape(N, 6), "S": V[8 * N:9 * N].copy(),
                "lam_x": np.asarray(sol["lam_x"], dtype=float).ravel(),
                "lam_g": np.asarray(sol["lam_g"], dtype=float).ravel()}

    # --- mill limits ---------------------------------------------------------------------------
    def _dwell_round(self, data: dict, res: dict):
        """Round the first interval's milling time onto the dwell limits with a re-solve.

        A planned milling period shorter than ``min_mill_min`` (or a rest shorter than
        ``min_rest_min``) has two neighbours the mill can run: none / the minimum. Each is fixed
        in turn as the first interval's milling and the NLP re-solved (warm solver); the lower
        cost wins (relax-and-round with a re-solve on the decision applied now). Returns
        (solution, extra ms, note)."""
        mill, N = self.guard.mill, self.N
        dt_min = self.interval_h * 60.0
        a = float(res["M"][0]) * dt_min
        lo_mill, lo_rest = max(mill.min_mill_min, 0.0), max(mill.min_rest_min, 0.0)
        if 0.5 < a < lo_mill - 0.5:
            cands = [0.0, lo_mill / dt_min]
        elif 0.5 < dt_min - a < lo_rest - 0.5:
            cands = [1.0, 1.0 - lo_rest / dt_min]
        else:
            return res, 0.0, ""
        cands = [c for c in cands if data["m_lb"][0] - 1e-9 <= c <= data["m_ub"][0] + 1e-9] or [0.0]
        t0 = time.perf_counter()
        best = None
        for c in cands:
            lbx, ubx = data["lbx"].copy(), data["ubx"].copy()
            lbx[N], ubx[N] = c, c
            M0 = res["M"].copy()
            M0[0] = c
            r = self._solve(data, warm=True, W=res["W"], M=M0, lbx=lbx, ubx=ubx)
            if r["ok"] and (best is None or r["f"] < best["f"]):
                best = r
        ms = (time.perf_counter() - t0) * 1e3
        if best is None:
            return res, ms, "dwell re-solve failed: nearest rounding"
        return best, ms, f"dwell: milling {a:.1f} -> {best['M'][0] * dt_min:.0f} min (re-solved)"

    # --- on/off --------------------------------------------------------------------------------
    def _binary(self, data: dict, res: dict):
        """Round milling to {0, 1}; optionally re-solve rpm with that pattern fixed. Returns
        (W, M, extra solve ms, loss = cost(binary) - cost(continuous), note)."""
        N = self.N
        Mb = np.where(res["M"] >= 0.5, 1.0, 0.0)
        Mb = np.minimum(Mb, np.where(data["m_ub"] >= 0.5, 1.0, 0.0))
        if np.allclose(Mb, res["M"], atol=1e-6):
            return res["W"], Mb, 0.0, 0.0, ""
        t0 = time.perf_counter()
        if self.cfg.onoff.resolve:
            lbx, ubx = data["lbx"].copy(), data["ubx"].copy()
            lbx[N:2 * N] = Mb
            ubx[N:2 * N] = Mb
            r2 = self._solve(data, warm=False, W=res["W"], M=Mb, lbx=lbx, ubx=ubx)
            ms = (time.perf_counter() - t0) * 1e3
            if r2["ok"]:
                return r2["W"], Mb, ms, r2["f"] - res["f"], ""
            note = f"binary re-solve failed ({r2['status']}): rounded only"
        else:
            ms, note = 0.0, ""
        V, _, _ = self._guess(data, False, res["W"], Mb)  # rounded plan, simulated; slack = violation
        if self._nlp is None:  # the solvers came compiled from the cache: the cost function is built now
            self._build()
        f = float(self._J(V, data["P"]))
        return res["W"], Mb, ms, f - res["f"], note

    # --- fallback and plans --------------------------------------------------------------------
    def _fallback(self, x0, t, pp, up, data, res, ms) -> Plan:
        N = self.N
        why = f"solver: {res['status']} after {res['iter']} it"
        status = Status("mpc", res["status"], False, res["iter"], ms, t_ceiling_c=self.cfg.temperature.ceiling_c)
        prev = self._prev
        s = None if prev is None else (t - prev.t_h) / self.interval_h
        if prev is not None and -1e-6 <= s < len(prev.W) - 1e-6:
            k = int(round(s))
            W = np.concatenate([prev.W[k:], np.full(k, prev.W[-1])])
            M = np.concatenate([prev.M[k:], np.zeros(k)])
            W = np.clip(W, data["lbx"][:N], data["ubx"][:N])
            M = np.clip(M, data["lbx"][N:2 * N], data["ubx"][N:2 * N])
            # temperature guard on the interval applied now
            M[0] = min(M[0], max_milling_for_ceiling(self.model, x0[4], W[0] * self.rpm_scale, self.interval_h,
                                                     self.cfg.temperature.ceiling_c))
            status.fallback, status.reason = "shifted", why + "; applying the shifted previous plan"
            U = np.column_stack([W * self.rpm_scale, M])
        else:
            status.fallback, status.reason = "rest", why + "; no previous plan: rest"
            U = np.zeros((N, 2))
        X = self.model.simulate(x0, U, self.interval_h, pp)
        return self._make_plan(x0, t, U, X, status)

    def _fixed_plan(self, x0, t, pp, U, status) -> Plan:
        X = self.model.simulate(x0, U, self.interval_h, pp)
        return self._make_plan(x0, t, U, X, status)

    def _states(self, x0, Z) -> np.ndarray:
        return np.vstack([x0[None, :], Z * X_SCALE])

    def _make_plan(self, x0, t, U, X, status: Status) -> Plan:
        dt = self.interval_h
        Tpk = interval_peaks(self.model, X, U, dt)
        status.t_peak_max_c = float(np.max(Tpk))
        on = self.cfg.onoff
        u_apply = applied_input_guarded(self.model, x0, U[0], dt, self.cfg.temperature.ceiling_c, on.round_minutes,
                                        on.mode == "binary")
        if self.guard.active():
            ceil = self.cfg.temperature.ceiling_c
            rpm_cap = self.rpm_hi
            T0s = [x0[4]] + [xs[4] for xs, _ in (self._scen or [])]
            from .mill import round_rpm

            r_dial = round_rpm(max(u_apply[0], 1.0), self.guard.mill, rpm_cap)  # the milling cap at the dial's rpm
            m_cap = min([float(np.clip((self.t_end_h - t) / dt, 0.0, 1.0))] + [
                max_milling_for_ceiling(self.model, T0, r_dial, dt, ceil) for T0 in T0s])
            u_apply, note = self.guard.enforce(u_apply, t, rpm_cap, m_cap)
            if note:
                status.reason = (status.reason + "; " if status.reason else "") + note
        return Plan(t, dt, U, X, np.asarray(Tpk, dtype=float), u_apply, status)


def _shift(v: np.ndarray, s: int, block: int = 1) -> np.ndarray:
    """Drop the first ``s`` blocks of ``block`` entries and repeat the last block to keep the length."""
    v = np.asarray(v, dtype=float)
    n = len(v) // block
    if n <= 1:
        return v.copy()
    s = min(max(int(s), 0), n - 1)
    if s == 0:
        return v.copy()
    return np.concatenate([v[s * block:], np.tile(v[-block:], s)])
