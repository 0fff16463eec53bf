"""Test doubles that follow the closed loop's protocols (estimator, controller, sensor), shared
by the tests that build a ``bmctl.loop.ClosedLoop`` by hand."""

from __future__ import annotations

import numpy as np


class FakeEstimate:
    """An estimate at the card's feed: what ``as_dict`` is read for."""

    def as_dict(self):
        return {"s_mean_um": 40.0, "s_std_um": 4.0, "r_mean": 0.02, "r_std": 0.02, "temperature_c": 25.0}


class FakeEstimator:
    """Records each input it is told to predict over (``inputs``); every estimate is the feed."""

    def __init__(self):
        self.inputs = []

    def predict(self, u, dt_h):
        self.inputs.append(tuple(u))

    def update(self, s_um, r, temperature_c=None):
        return FakeEstimate()

    def estimate(self):
        return FakeEstimate()

    def get_state(self):
        return {}

    def set_state(self, state):
        pass


class FakeController:
    """Returns the plan it was given, every interval."""

    interval_h = 0.5

    def __init__(self, plan):
        self.out = plan

    def plan(self, x_est, t_h, p=None, u_prev=None):
        return self.out

    def get_state(self):
        return {}

    def set_state(self, state):
        pass


#: "not given" where None is a value a test hands over (a sensor that returns None)
DEFAULT = object()


class FakeSensor:
    """Returns the sample it was given (default: five particles of 10 um, r 0.1)."""

    def __init__(self, out=DEFAULT):
        self.out = (np.full(5, 10.0), np.full(5, 0.1)) if out is DEFAULT else out

    def sample(self, mill, rng):
        return self.out
