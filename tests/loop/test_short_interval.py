"""A batch that is not a whole number of control intervals ends with a shorter interval: the
controller's milling share is a share of its nominal interval (docs/control.md, ``u_apply``), so
the loop mills the planned minutes there, not that share of the shorter interval."""

import numpy as np
import pytest

from bmctl.loop import ClosedLoop, LoopConfig, interval_share

from ..api.test_loop_protocols import FakeController, FakeEstimator, FakeMill, FakePlan, FakeSensor


class RecordingMill(FakeMill):
    def __init__(self):
        self.runs = []

    def advance(self, rpm, hours, milling=1.0):
        self.runs.append((rpm, hours, milling))


class RecordingEstimator(FakeEstimator):
    def __init__(self):
        self.inputs = []

    def predict(self, u, dt_h):
        self.inputs.append((tuple(u), dt_h))


def _milling_minutes(runs):
    return 60.0 * sum(h * m for rpm, h, m in runs if rpm > 0)


@pytest.mark.parametrize("hours, u, minutes", [
    # 2.2 h in 0.5 h intervals: the last one is 12 min; the plan's 10 of 30 min (1/3) ran as 4 min
    (2.2, (300.0, 1.0 / 3.0), 4 * 10.0 + 10.0),
    # 0.3 h, shorter than one interval: a plan to mill all 18 min (0.6 of 30) milled 10.8 min
    (0.3, (300.0, 0.6), 18.0),
    # more milling than the short interval holds: all of it
    (2.2, (300.0, 1.0), 4 * 30.0 + 12.0),
])
def test_the_last_short_interval_mills_the_planned_minutes(hours, u, minutes):
    mill, est = RecordingMill(), RecordingEstimator()
    lp = ClosedLoop(mill, FakeSensor(), est, FakeController(FakePlan(u)), np.random.default_rng(0),
                    LoopConfig(hours=hours, sample_every_h=0.5))
    recs = [lp.step() for _ in range(lp.steps)]
    assert _milling_minutes(mill.runs) == pytest.approx(minutes)
    # the estimator is told what the mill ran, and the record gives the share of the interval it covers
    assert 60.0 * sum(uu[1] * dt for uu, dt in est.inputs) == pytest.approx(minutes)
    starts = [0.0] + [r.t_h for r in recs[:-1]]
    assert 60.0 * sum(r.milling * (r.t_h - t0) for r, t0 in zip(recs, starts)) == pytest.approx(minutes)


def test_a_full_interval_keeps_the_share_bit_for_bit():
    for m in (0.0, 1.0 / 3.0, 0.7, 1.0):
        assert interval_share(m, 0.5, 0.5) == m
        assert interval_share(m, 0.25, 0.25) == m


def test_a_short_last_interval_leaves_no_phase_a_log_would_refuse():
    """Whole advised minutes in a last interval seconds longer than whole minutes: the share
    mills the seconds on (a 3-s rest would be refused by ``campaign log``, bmctl.schedule.short_phase)."""
    from bmctl.schedule import short_phase

    for dt_min in (10.05, 10.099, 0.05, 7.0, 29.99):
        for mill_min in range(0, 31):
            share = interval_share(mill_min / 30.0, 0.5, dt_min / 60.0)
            assert short_phase(dt_min / 60.0, 300.0, share) == "", (dt_min, mill_min, share)
            if mill_min == 0:
                assert share == 0.0
            else:  # the advised minutes, or all of the interval, never fewer
                assert share * dt_min >= min(mill_min, dt_min) - 1e-9
