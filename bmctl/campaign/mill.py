"""The campaign's loop: a person at a real mill as the :class:`bmctl.loop.Mill`, the recorded
micrographs as the :class:`bmctl.loop.Sensor`, and :class:`CampaignLoop`, a
:class:`bmctl.loop.ClosedLoop` on the campaign's clock.

``OperatorMill.advance`` replays what ``campaign log`` recorded (it cannot run a mill: the
person did); its temperature is the last reading (the card's ambient before any). The
sensor returns the particles ``campaign sample`` stored. The runner's ``apply`` (mill, then
estimator prediction) is used unchanged; :meth:`CampaignLoop.decide_at` and
:meth:`CampaignLoop.observe_at` take the campaign's time instead of the interval count,
because a real batch is logged in intervals of any length and sampled at any time.
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..loop import ClosedLoop, estimate_vectors


class OperatorMill:
    """A person at a real mill: ``advance`` records, the truth is unknown (NaN moments).

    Parameters
    ----------
    ambient_c : float
        Vial temperature before the first reading (degC).
    """

    def __init__(self, ambient_c: float):
        self.t_h = 0.0
        self._temperature_c = float(ambient_c)

    def advance(self, rpm: float, hours: float, milling: float = 1.0) -> None:
        """Account for ``hours`` the mill ran (as logged)."""
        self.t_h += float(hours)

    def read_temperature(self, temperature_c: float) -> None:
        """A vial-temperature reading (degC)."""
        self._temperature_c = float(temperature_c)

    @property
    def temperature_c(self) -> float:
        return self._temperature_c

    def moments(self) -> dict:
        """Unknown at a real mill: NaN moments, the last temperature reading."""
        nan = math.nan
        return {"s_mean_um": nan, "s_std_um": nan, "r_mean": nan, "r_std": nan, "temperature_c": self._temperature_c}

    def get_state(self) -> dict:
        return {"t_h": self.t_h, "temperature_c": self._temperature_c}

    def set_state(self, state: dict) -> None:
        self.t_h = float(state["t_h"])
        self._temperature_c = float(state["temperature_c"])


class RecordedSensor:
    """The micrographs measured by ``campaign sample``: :meth:`sample` returns the one queued."""

    def __init__(self):
        self.queued: tuple[np.ndarray, np.ndarray] | None = None

    def sample(self, mill, rng) -> tuple[np.ndarray, np.ndarray]:
        """``(s_um, r)`` of the queued sample (the rng is not used: the person took it)."""
        if self.queued is None:
            raise RuntimeError("no sample queued")
        out, self.queued = self.queued, None
        return out


class CampaignLoop(ClosedLoop):
    """:class:`bmctl.loop.ClosedLoop` whose decisions and observations happen at logged times."""

    def decide_at(self, t_h: float, history=None):
        """The controller's plan at batch time ``t_h`` from the current estimate and ``u_prev``
        (as :meth:`ClosedLoop.decide`, which plans at ``k * interval_h``; a scenario MPC gets the
        filter's scenarios as there). ``history``: the logged intervals ``(hours, rpm, milling)``,
        for a controller that plans from the mill's record (dwell periods and switches used)."""
        x, p = estimate_vectors(self.est)
        t0 = time.perf_counter()
        kw = {"history": history} if history is not None and getattr(self.controller, "uses_history", False) else {}
        n_spread = getattr(self.controller, "spread_particles", 0)
        if n_spread:  # a plan on operable schedules: the filter's particles as its spread
            from ..control.robust import particle_scenarios

            plan = self.controller.plan(x, float(t_h), p=p, u_prev=self.u_prev,
                                        scenarios=particle_scenarios(self.estimator, n_spread), **kw)
        elif getattr(self.controller, "n_scen", 1) > 1:  # scenario MPC: the filter's spread, as ClosedLoop.decide
            from ..control.robust import filter_scenarios

            plan = self.controller.plan(x, float(t_h), p=p, u_prev=self.u_prev,
                                        scenarios=filter_scenarios(self.est, self.controller.n_scen - 1), **kw)
        else:
            plan = self.controller.plan(x, float(t_h), p=p, u_prev=self.u_prev, **kw)
        st = plan.status
        solve_ms = st.solve_ms if st.solve_ms else (time.perf_counter() - t0) * 1e3
        return plan, solve_ms

    def observe_at(self, s_um=None, r=None, temperature_c: float | None = None) -> dict:
        """Weigh in what was observed now (a sample, a temperature reading, both or neither:
        then the estimate is read, which applies the deferred process noise unless the filter keeps
        it for a sample: ``moment_noise_at = "sample"``); returns the estimate dict."""
        predicted = None
        if s_um is None and temperature_c is None:
            est = self.estimator.estimate()
        else:
            if temperature_c is not None:
                predicted = predicted_temperature(self.estimator)
                self.mill.read_temperature(temperature_c)
            if s_um is not None:
                self.sensor.queued = (np.asarray(s_um, dtype=float), np.asarray(r, dtype=float))
                s_um, r = self.sensor.sample(self.mill, self.sample_rng)
            est = self.estimator.update(s_um, r, temperature_c=temperature_c)
        self.est = est.as_dict()
        if predicted is not None:  # the reading and what the estimate expected just before it
            self.est["reading_c"] = float(temperature_c)
            self.est["reading_predicted_c"], self.est["reading_predicted_sd_c"] = predicted
        return self.est


def predicted_temperature(estimator) -> tuple[float, float]:
    """Weighted mean and std (degC) of a particle estimator's vial temperature now, before a
    reading (its own ``reading_prediction`` where it has one: the heating gain's prior at the first
    reading counts; NaN for an estimator without particles)."""
    if hasattr(estimator, "reading_prediction"):
        return estimator.reading_prediction()
    X, w = getattr(estimator, "X", None), getattr(estimator, "weights", None)
    if X is None or w is None:
        return math.nan, math.nan
    T = np.asarray(X, dtype=float)[:, 4]
    m = float(w @ T)
    return m, float(math.sqrt(max(float(w @ (T - m) ** 2), 0.0)))
