"""Baselines with the MPC's ``plan`` interface: the paper's open-loop recipes and an LQR.

* :class:`RecipeController` -- a fixed schedule: rpm, continuous or ``mill_min``/``rest_min``
  cycles (the paper's 300 rpm continuous and 400 rpm 30/10); ignores the state.
* :class:`LQRController` -- velocity-form LQR on rpm with integral action on one moment,
  designed with ``control.dlqr`` on the moment model re-linearised at every interval
  (gain scheduling), with the same rpm bounds, rate limit and a temperature guard that
  lowers the milling fraction so the predicted peak stays under the ceiling.
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..errors import InputError
from ..physics.constants import TIME_EPS_H
from .base import (Plan, Reference, Status, _CallableReference, batch_end_h, applied_input, applied_input_guarded,
                   check_gamma_delta, check_rpm_range, check_u_prev, check_x, interval_peaks, max_milling_for_ceiling,
                   rpm_window)
from .config import TARGET_KEYS, LQRConfig, RecipeConfig, check_lqr_track, target_centre
from .mill import MillGuard
from .mpc import ERR_FLOOR, X_SCALE


class _Base:
    kind = "base"

    def __init__(self, cfg, model, reference=None):
        self.cfg = cfg
        self.model = model
        self.t_end_h = float(cfg.batch_hours if cfg.batch_hours is not None else model.card.process.hours)
        self.reference = Reference.from_config(cfg) if reference is None else Reference.make(reference)
        self.guard = MillGuard(cfg.mill, cfg.interval_h or 0.5)

    def set_target(self, target, t_end_h: float | None = None) -> None:
        """As :meth:`bmctl.control.mpc.MPCController.set_target`."""
        self.reference = Reference.make(target)
        if t_end_h is not None:
            self.t_end_h = batch_end_h(t_end_h)

    def reset(self) -> None:
        pass

    def get_state(self) -> dict:
        """Plain-data state for checkpoints: the mill-limit guard's (the recipe is a function of time)."""
        return {"guard": self.guard.get_state()}

    def set_state(self, state: dict) -> None:
        """Restore a state from :meth:`get_state`."""
        if "guard" in state:
            self.guard.set_state(state["guard"])

    def _plan(self, x0, t, pp, U, status, round_minutes=True, ceiling=None) -> Plan:
        dt = self.interval_h
        U = np.atleast_2d(np.asarray(U, dtype=float))
        X = self.model.simulate(x0, U, dt, pp)
        Tpk = interval_peaks(self.model, X, U, dt)
        status.t_peak_max_c = float(np.max(Tpk))
        if ceiling is None:
            ua = applied_input(U[0], dt, round_minutes)
        else:
            ua = applied_input_guarded(self.model, x0, U[0], dt, ceiling, round_minutes)
        if self.guard.active() and self.kind != "recipe":
            self.guard.interval_h = dt
            from .mill import round_rpm

            # rpm onto the dial: never above a clipped rpm; the milling cap from the rounded rpm
            rpm_cap = self.model.rpm_max
            if getattr(self.cfg, "ceiling_mode", "guard") == "clip" and ua[0] > 0:
                rpm_cap = min(rpm_cap, float(ua[0]))
            r = round_rpm(max(ua[0], 1.0), self.guard.mill, rpm_cap) if ua[0] > 0 else 1.0
            m_cap = 1.0 if ceiling is None else max_milling_for_ceiling(self.model, x0[4], max(r, 1.0), dt, ceiling)
            ua, note = self.guard.enforce(ua, t, rpm_cap, min(m_cap, float(U[0, 1]) + 1e-9))
            if note:
                status.reason = (status.reason + "; " if status.reason else "") + note
        return Plan(t, dt, U, X, Tpk, ua, status)

    @staticmethod
    def _check(x_est, t_h, model, p, u_prev):
        x0 = check_x(x_est)
        pp = check_gamma_delta(model, p)
        up = check_u_prev(u_prev, model)
        t = float(t_h)
        if not math.isfinite(t) or t < 0:
            raise InputError(f"t_h: must be a finite number >= 0 (got {t_h})")
        return x0, pp, up, t


class RecipeController(_Base):
    """The paper's open-loop schedule as a controller (state ignored)."""

    kind = "recipe"

    def __init__(self, cfg: RecipeConfig, model, reference=None):
        super().__init__(cfg, model, reference)
        if cfg.rpm > model.rpm_max:
            raise InputError(f"controller {cfg.name}: rpm: {cfg.rpm:g} exceeds the mill's rpm_max {model.rpm_max:g} "
                             "(the card's mill.rpm_max)")
        cyc = None if cfg.mill_min is None else (cfg.mill_min + cfg.rest_min) / 60.0
        self.cycle_h = cyc
        self.interval_h = float(cfg.interval_h if cfg.interval_h is not None else (cyc or 0.5))

    def milling_fraction(self, a: float, b: float) -> float:
        """Share of [a, b] (batch hours) the recipe spends milling (none after the batch end)."""
        b = min(b, self.t_end_h)
        if b <= a:
            return 0.0
        if self.cycle_h is None:
            return (b - a) / self.interval_h
        mill_h = self.cfg.mill_min / 60.0

        def F(t):  # milling hours in [0, t]
            n = math.floor(t / self.cycle_h + 1e-12)
            return n * mill_h + min(t - n * self.cycle_h, mill_h)

        return float(np.clip((F(b) - F(a)) / self.interval_h, 0.0, 1.0))

    def plan(self, x_est, t_h: float, p=None, u_prev=None) -> Plan:
        x0, pp, up, t = self._check(x_est, t_h, self.model, p, u_prev)
        t0 = time.perf_counter()
        dt = self.interval_h
        n = max(1, int(math.ceil((self.t_end_h - t) / dt - 1e-9)))
        U = np.array([[self.cfg.rpm, self.milling_fraction(t + k * dt, t + (k + 1) * dt)] for k in range(n)])
        U[U[:, 1] <= 0, 0] = 0.0
        status = Status("recipe", "open-loop", True, 0, 0.0, t_ceiling_c=float("nan"),
                        reason="batch finished: rest" if t >= self.t_end_h - TIME_EPS_H else "")
        plan = self._plan(x0, t, pp, U, status, self.cfg.round_minutes)
        status.solve_ms = (time.perf_counter() - t0) * 1e3
        return plan


class LQRController(_Base):
    """Gain-scheduled, velocity-form LQR on rpm with integral action on one target moment.

    Augmented state ``xi = (dx_k / X_SCALE, e_k)``, ``dx_k = x_k - x_{k-1}``, ``e_k`` the
    relative error of the tracked moment; input ``dw_k = (rpm_k - rpm_{k-1}) / rpm_max``.
    ``(A, B)`` is the discrete linearisation of the moment model's step at
    ``(x_k, rpm_{k-1}, milling)``; ``K = dlqr(Aa, Ba, diag(q_dx.., q_error), r_du)``.
    """

    kind = "lqr"

    def __init__(self, cfg: LQRConfig, model, reference=None):
        check_rpm_range(cfg, model.rpm_max)  # no speed left to mill at: refused, not advised above the mill's top
        super().__init__(cfg, model, reference)
        self._check_track(self.reference)
        self.interval_h = float(cfg.interval_h)
        self.rpm_scale = float(model.const.rpm_max)
        self._jac = None
        self.reset()

    def _check_track(self, reference: Reference) -> None:
        """Refuse a reference the LQR cannot track (:func:`bmctl.control.config.check_lqr_track`); a
        callable reference is known only at plan time."""
        if not isinstance(reference, _CallableReference):
            check_lqr_track(self.cfg.lqr.track, reference.points, "target", f"controller {self.cfg.name or 'lqr'}")

    def set_target(self, target, t_end_h: float | None = None) -> None:
        """As :meth:`bmctl.control.mpc.MPCController.set_target`; a target that never names the
        tracked moment (or, with ``lqr.track`` unset, names only D-values) is refused."""
        reference = Reference.make(target)
        self._check_track(reference)
        self.reference = reference
        if t_end_h is not None:
            self.t_end_h = batch_end_h(t_end_h)

    def reset(self) -> None:
        self._x_last = None
        self._t_last = None
        self._rpm_last = None
        self._K = None
        if hasattr(self, "guard"):
            self.guard.reset()

    def get_state(self) -> dict:
        """Last state, time, rpm and gain as plain data (the Jacobians are rebuilt)."""
        return {"x_last": self._x_last, "t_last": self._t_last, "rpm_last": self._rpm_last,
                "K": None if self._K is None else np.asarray(self._K, dtype=float), "guard": self.guard.get_state()}

    def set_state(self, state: dict) -> None:
        """Restore a state from :meth:`get_state`."""
        if "guard" in state:
            self.guard.set_state(state["guard"])
        self._x_last = None if state["x_last"] is None else np.asarray(state["x_last"], dtype=float)
        self._t_last = None if state["t_last"] is None else float(state["t_last"])
        self._rpm_last = None if state["rpm_last"] is None else float(state["rpm_last"])
        self._K = None if state["K"] is None else np.asarray(state["K"], dtype=float)

    def _jacobians(self):
        if self._jac is None:
            import casadi as ca

            F = self.model.casadi_step(self.interval_h)
            x, u, p = ca.SX.sym("x", 6), ca.SX.sym("u", 2), ca.SX.sym("p", 2)
            y = F(x, u, p)
            self._jac = ca.Function("AB", [x, u, p], [ca.jacobian(y, x), ca.jacobian(y, u)])
        return self._jac

    def gain(self, x, rpm: float, milling: float, p, key: str, scale: float):
        """(K, A, B) of the augmented velocity-form problem at (x, rpm, milling)."""
        import control

        A, B = (np.asarray(v, dtype=float) for v in self._jacobians()(x, [rpm, milling], p))
        Dm = np.diag(X_SCALE)
        Di = np.diag(1.0 / X_SCALE)
        As = Di @ A @ Dm
        Bs = Di @ B[:, [0]] * self.rpm_scale
        i = TARGET_KEYS.index(key)
        C = np.zeros((1, 6))
        C[0, i] = X_SCALE[i] / scale
        Aa = np.block([[As, np.zeros((6, 1))], [C @ As, np.ones((1, 1))]])
        Ba = np.vstack([Bs, C @ Bs])
        t = self.cfg.lqr
        Q = np.diag([t.q_dx] * 6 + [t.q_error])
        K, _, _ = control.dlqr(Aa, Ba, Q, np.array([[t.r_du]]))
        return np.asarray(K, dtype=float), A, B

    def plan(self, x_est, t_h: float, p=None, u_prev=None) -> Plan:
        x0, pp, up, t = self._check(x_est, t_h, self.model, p, u_prev)
        cfg, dt = self.cfg, self.interval_h
        ceiling = cfg.temperature.ceiling_c
        if t >= self.t_end_h - TIME_EPS_H:
            done = Status("lqr", "batch_done", True, reason="batch finished: rest", t_ceiling_c=ceiling)
            return self._plan(x0, t, pp, np.zeros((1, 2)), done, cfg.round_minutes)
        t0 = time.perf_counter()
        if up is not None and up[0] > 0 and up[1] > 0:
            rpm_prev = float(up[0])
        elif self._rpm_last is not None:
            rpm_prev = self._rpm_last
        else:
            rpm_prev = cfg.lqr.rpm_start
        lo, hi, _ = rpm_window(cfg.bounds, self.model.rpm_max, up)
        d = self.reference.at(min(t + dt, self.t_end_h))
        key = cfg.lqr.track if cfg.lqr.track is not None else next((k for k in TARGET_KEYS if k in d), None)
        status = Status("lqr", "dlqr", True, 1, 0.0, t_ceiling_c=ceiling)
        m_nom = min(cfg.lqr.milling, float(np.clip((self.t_end_h - t) / dt, 0.0, 1.0)))
        rpm = float(np.clip(rpm_prev, max(lo, cfg.bounds.rpm_min), hi))
        if key is None or key not in d:
            status.reason = "no target on the tracked moment: holding rpm"
        else:
            ref = target_centre(d[key])
            scale = max(abs(ref), ERR_FLOOR[key])
            i = TARGET_KEYS.index(key)
            if i >= 4:
                raise InputError(f"lqr: track: {key} is not a state of the moment model (track a moment)")
            e = (x0[i] - ref) / scale
            consecutive = self._t_last is not None and abs(t - self._t_last - dt) < 1e-6
            dxs = (x0 - self._x_last) / X_SCALE if consecutive and self._x_last is not None else np.zeros(6)
            try:
                K, _, _ = self.gain(x0, max(rpm_prev, 1.0), max(m_nom, 1e-3), pp, key, scale)
                self._K = K
            except Exception as exc:  # not stabilisable at this point, numerical trouble
                status.solver_status, status.success = "dlqr failed", False
                if self._K is not None:
                    K = self._K
                    status.fallback, status.reason = "shifted", f"dlqr: {exc}; previous gain"
                else:
                    K = None
                    status.fallback, status.reason = "rest", f"dlqr: {exc}; holding rpm"
            if K is not None:
                dw = float(-(K @ np.concatenate([dxs, [e]]))[0])
                rpm = float(np.clip(rpm_prev + dw * self.rpm_scale, lo, hi))
        if cfg.ceiling_mode == "clip":  # keep milling, clip rpm to the highest that keeps the ceiling
            rpm_ok = _max_rpm_for_ceiling(self.model, x0[4], m_nom, dt, ceiling, lo, rpm)
            if rpm_ok < rpm - 1e-9:
                status.reason = (status.reason + "; " if status.reason else "") + \
                    f"ceiling clip: rpm {rpm:.0f} -> {rpm_ok:.0f}"
                rpm = rpm_ok
        m_cap = max_milling_for_ceiling(self.model, x0[4], rpm, dt, ceiling)
        milling = min(m_nom, m_cap)
        if milling < m_nom - 1e-9:  # named in the minutes applied (whole minutes, as _plan rounds them)
            applied = applied_input_guarded(self.model, x0, (rpm, milling), dt, ceiling, cfg.round_minutes)[1]
            a, b = (round(m * dt * 60.0, 1) for m in (m_nom, applied))
            if b < a:
                status.reason = (status.reason + "; " if status.reason else "") + \
                    f"temperature guard: milling {a:g} -> {b:g} min"
        self._x_last, self._t_last, self._rpm_last = x0.copy(), t, rpm
        status.solve_ms = (time.perf_counter() - t0) * 1e3
        return self._plan(x0, t, pp, np.array([[rpm, milling]]), status, cfg.round_minutes, ceiling)


def _max_rpm_for_ceiling(model, T0: float, milling: float, dt_h: float, ceiling_c: float, lo: float,
                         hi: float) -> float:
    """Highest rpm in [lo, hi] whose peak temperature with ``milling`` stays <= the ceiling (bisection;
    ``lo`` when none does: the guard then lowers the milling fraction)."""
    def ok(r):
        return max_milling_for_ceiling(model, T0, r, dt_h, ceiling_c) >= milling - 1e-9

    if ok(hi):
        return float(hi)
    if not ok(lo):
        return float(lo)
    a, b = float(lo), float(hi)
    for _ in range(30):
        m = 0.5 * (a + b)
        a, b = (m, b) if ok(m) else (a, m)
    return a
