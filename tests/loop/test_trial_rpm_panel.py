"""trial.png's rpm panel: each interval's speed drawn over the interval, the first from t = 0
(a step over the interval-end times left the first interval's speed undrawn)."""

import numpy as np
import pytest

from bmctl import io
from bmctl.scenario import Scenario
from bmctl.trial import figures, trajectory_header

RPM = [300.0, 150.0, 0.0, 220.0]


def _value_at(line, x: float) -> float:
    """The drawn line's value at ``x``: the horizontal piece of its path over ``x``."""
    v = line.get_path().vertices
    for (x0, y0), (x1, y1) in zip(v[:-1], v[1:]):
        if y0 == y1 and min(x0, x1) <= x < max(x0, x1):
            return float(y0)
    raise AssertionError(f"nothing drawn at t = {x} h")


@pytest.fixture
def rpm_line(tmp_path, monkeypatch):
    header = trajectory_header()
    rows = []
    for k, rpm in enumerate(RPM):
        row = dict.fromkeys(header, 1.0)
        row.update(step=k, t_h=0.5 * (k + 1), rpm=rpm, milling=0.5 if rpm else 0.0, solver_status=0)
        rows.append(",".join(str(row[h]) for h in header))
    traj = tmp_path / "trajectory.csv"
    traj.write_text(",".join(header) + "\n" + "\n".join(rows) + "\n", encoding="utf-8")
    sc = Scenario.model_validate({"scenario": {"name": "n", "description": "d"}, "model": "m.toml",
                                  "controller": {"config": "c.toml"}, "hours": 2.0})
    figs = []
    monkeypatch.setattr(io, "savefig", lambda fig, path, **kw: figs.append(fig))
    figures(sc, traj, tmp_path, None)
    assert len(figs) == 1
    ax = figs[0].axes[3]  # second row, first panel
    assert ax.get_ylabel() == "rpm"
    yield ax.lines[0]
    import matplotlib.pyplot as plt

    plt.close(figs[0])


def test_each_interval_speed_is_drawn_from_its_start(rpm_line):
    for k, rpm in enumerate(RPM):
        for x in np.linspace(0.5 * k, 0.5 * (k + 1), 5)[:-1]:  # from the interval's start to just before its end
            assert _value_at(rpm_line, x) == rpm, (k, x)
    assert rpm_line.get_path().vertices[:, 0].max() == pytest.approx(2.0)  # to the batch end, no further
