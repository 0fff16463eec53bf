"""Every hidden-mill campaign in ``results/`` kept its controller's dwell minimums.

Each ``results/hidden_mills*.json`` holds, per mill, the step log of the advices the scripted operator
ran (``t_h``, ``rpm``, ``mill_min``: each interval mills first, then rests). The log is rebuilt into
(hours, rpm) segments and checked against the ``[mill]`` limits of the controller the file names with
``bmctl.control.mill.check_schedule``, written independently of the planner's own operability test:
no milling period or rest between two milling periods is shorter than its minimum, the on/off
switches fit the budget, every rpm is on the dial. A re-plan that
ended a logged 1-min rest by milling at once broke this in 20 of these files before the open period
was counted.
"""

from __future__ import annotations

import json

import pytest

from bmctl.control.config import load_controller
from bmctl.control.mill import check_schedule
from tests.conftest import ROOT

#: hidden-mill results that log no campaigns: the sample-noise studies and the floor (a summary of other files' runs)
NO_CAMPAIGNS = {"hidden_mills_floor.json", "hidden_mills_noise.json", "hidden_mills_noise_samples1000.json"}
FILES = sorted(p for p in (ROOT / "results").glob("hidden_mills*.json") if p.name not in NO_CAMPAIGNS)


def log_segments(case: dict) -> list[tuple[float, float]]:
    """(hours, rpm) segments of one mill's step log, milling first in each interval, rests at rpm 0."""
    steps = case["steps"]
    segs = []
    for k, a in enumerate(steps):
        end = steps[k + 1]["t_h"] if k + 1 < len(steps) else float(case["hours"])
        length_min = (end - a["t_h"]) * 60.0
        mill_min = float(a["mill_min"]) if a["rpm"] > 0 else 0.0
        if mill_min > 0:
            segs.append((mill_min / 60.0, float(a["rpm"])))
        if length_min - mill_min > 1e-9:
            segs.append(((length_min - mill_min) / 60.0, 0.0))
    return segs


def test_the_segments_of_a_log_follow_its_steps():
    case = {"hours": 1.5, "steps": [{"t_h": 0.0, "rpm": 300.0, "mill_min": 29},
                                    {"t_h": 0.5, "rpm": 300.0, "mill_min": 30},
                                    {"t_h": 1.0, "rpm": 0.0, "mill_min": 30}]}
    assert log_segments(case) == pytest.approx([(29 / 60, 300.0), (1 / 60, 0.0), (0.5, 300.0), (0.5, 0.0)])
    mill = load_controller(ROOT / "controllers" / "mpc-default.toml").mill
    assert check_schedule(log_segments(case), mill) == ["segment 1: rest 1.0 min < 5 min"]


@pytest.mark.parametrize("path", FILES, ids=[p.name for p in FILES])
def test_every_logged_campaign_keeps_the_dwell_minimums(path):
    data = json.loads(path.read_text(encoding="utf-8"))
    controller = data.get("settings", {}).get("controller")
    cases = [c for c in data.get("cases", []) if c.get("steps")]
    assert controller and cases, f"{path.name}: no campaign step logs (a study without campaigns: list it in NO_CAMPAIGNS)"
    mill = load_controller(ROOT / controller).mill
    broken = {c["case"]: v for c in cases
              if (v := check_schedule(log_segments(c), mill))}
    assert not broken, f"{path.name}: {broken}"


@pytest.mark.parametrize("name", sorted(NO_CAMPAIGNS))
def test_the_files_left_out_log_no_campaigns(name):
    data = json.loads((ROOT / "results" / name).read_text(encoding="utf-8"))
    assert not any(c.get("steps") for c in data.get("cases", []) if isinstance(c, dict)), name
