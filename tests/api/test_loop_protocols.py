"""ClosedLoop as a library user builds it: an object that does not follow its protocol, a
sensor or controller that returns the wrong thing, or a bad LoopConfig is refused with an error
that names the argument (not an AttributeError or a ZeroDivisionError from inside the loop)."""

import math

import numpy as np
import pytest

from bmctl.errors import InputError
from bmctl.loop import ClosedLoop, LoopConfig

from ..loopfakes import FakeController, FakeEstimator, FakeSensor


class FakeMill:
    temperature_c = 25.0

    def advance(self, rpm, hours, milling=1.0):
        pass

    def moments(self):
        return {"s_mean_um": 40.0, "temperature_c": 25.0}

    def get_state(self):
        return {}

    def set_state(self, state):
        pass


class _Status:
    solve_ms, fallback, success = 1.0, "none", True


class FakePlan:
    def __init__(self, u):
        self.u_apply, self.status = u, _Status()


def _loop(mill=None, sensor=None, est=None, ctrl=None, rng=None, cfg=None):
    return ClosedLoop(mill or FakeMill(), sensor or FakeSensor(), est or FakeEstimator(), ctrl or FakeController(FakePlan((300.0, 1.0))),
                      np.random.default_rng(0) if rng is None else rng, cfg or LoopConfig(hours=1.0, sample_every_h=0.5))


def test_fakes_following_the_protocols_run():
    lp = _loop()
    recs = [lp.step() for _ in range(lp.steps)]
    assert [r.sampled for r in recs] == [1, 1]


@pytest.mark.parametrize("role", ["mill", "sensor", "estimator", "controller"])
def test_an_object_without_its_protocol_is_refused_naming_the_argument(role):
    with pytest.raises(TypeError, match=rf"^{role}: object lacks .* protocol"):
        _loop(**{{"estimator": "est", "controller": "ctrl"}.get(role, role): object()})


def test_a_seed_for_sample_rng_is_refused():
    with pytest.raises(TypeError, match="sample_rng: must be a numpy.random.Generator"):
        _loop(rng=3)


@pytest.mark.parametrize("hours,every", [(-1.0, 0.5), (math.nan, 0.5), ("1", 0.5), (1.0, 0.0), (1.0, -1.0)])
def test_loop_config_refuses_durations_that_are_not_positive_hours(hours, every):
    with pytest.raises(InputError, match="(hours|sample_every_h): must be a finite number of hours > 0"):
        LoopConfig(hours=hours, sample_every_h=every)


def test_a_controller_interval_of_zero_is_refused():
    ctrl = FakeController(FakePlan((300.0, 1.0)))
    ctrl.interval_h = 0.0
    with pytest.raises(InputError, match="controller.interval_h: must be"):
        _loop(ctrl=ctrl)


@pytest.mark.parametrize("out", [np.full(5, 10.0), None, {"s_um": 1}])
def test_a_sensor_that_returns_no_pair_is_named(out):
    lp = _loop(sensor=FakeSensor(out))
    with pytest.raises(TypeError, match=r"sensor.sample: must return a pair \(s_um, r\)"):
        lp.step()


def test_a_sensor_pair_of_unequal_lengths_is_named():
    lp = _loop(sensor=FakeSensor((np.ones(5), np.ones(4) * 0.1)))
    with pytest.raises(ValueError, match="sensor.sample: s_um and r must be 1-D arrays of one length"):
        lp.step()


@pytest.mark.parametrize("out", [(300.0, 1.0), None])
def test_a_controller_that_returns_no_plan_is_named(out):
    lp = _loop(ctrl=FakeController(out))
    with pytest.raises(TypeError, match="controller.plan: must return a Plan"):
        lp.step()


@pytest.mark.parametrize("u", [(300.0, 2.0), (-5.0, 1.0), (math.nan, 1.0), (300.0, 1.0, 3.0)])
def test_a_plan_input_out_of_range_is_refused_before_the_mill_runs(u):
    lp = _loop(ctrl=FakeController(FakePlan(u)))
    with pytest.raises(ValueError, match="controller.plan: u_apply must be"):
        lp.step()


@pytest.mark.parametrize("segments, every, needle", [
    ([(-1.0, 300.0)], 0.5, r"segments\[0\]: must be \(hours, rpm\)"),
    ([(1.0, 300.0), (float("nan"), 0.0)], 0.5, r"segments\[1\]"),
    ([(1.0, 300.0)], 0.0, "record_every_h: must be a finite number of hours > 0"),
])
def test_run_open_loop_refuses_negative_hours_and_a_zero_recording_interval(segments, every, needle):
    from bmctl.errors import InputError
    from bmctl.loop import run_open_loop
    from bmctl.plant import make_plant

    plant = make_plant("models/alni-1to1-300rpm-lab.toml", seed=0, particles=100)
    with pytest.raises(InputError, match=needle):
        run_open_loop(plant, segments, every, lambda t, m: None)
