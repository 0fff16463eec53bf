"""``bmctl estimate``'s figure (:func:`bmctl.estimate.run.plot_estimates`), read as matplotlib objects:
the time axis starts at 0, and a single sample time still shows its 90 % interval."""

from __future__ import annotations

import numpy as np
import pytest

from bmctl import io as bio
from bmctl.estimate.filter import Estimate
from bmctl.estimate.run import Sample, plot_estimates

NAMES = ("s_mean_um", "s_std_um", "r_mean", "r_std", "temperature_c", "hardening", "gamma_mult")


def _estimates(times) -> list[Estimate]:
    out = []
    for i, t in enumerate(times):
        mean = np.array([60.0 + i, 30.0, 0.1, 0.05, 50.0, 0.1 * (i + 1), 1.1])
        out.append(Estimate(t_h=float(t), names=NAMES, mean=mean, q05=mean * 0.9, q95=mean * 1.1, ess=200.0 - i))
    return out


def _samples(times) -> list[Sample]:
    rng = np.random.default_rng(0)
    return [Sample(t_h=float(t), s_um=rng.lognormal(np.log(60.0), 0.4, 50), r=rng.uniform(0.0, 0.2, 50))
            for t in times]


@pytest.fixture
def drawn(monkeypatch, tmp_path):
    """plot_estimates' figure, kept instead of saved."""
    figs = []
    monkeypatch.setattr(bio, "savefig", lambda fig, path, **kw: figs.append(fig))
    yield lambda times: (plot_estimates(tmp_path / "estimate.png", _estimates(times), _samples(times), title="t"),
                         figs[-1])[1]
    import matplotlib.pyplot as plt

    plt.close("all")


def _used(fig):
    return [ax for ax in fig.axes if ax.axison]


def test_time_axis_starts_at_0_not_at_the_first_sample(drawn):
    fig = drawn([0.5, 1, 2, 4, 8])
    axes = _used(fig)
    assert len(axes) == len(NAMES) + 1  # every quantity and the effective sample size
    for ax in axes:
        lo, hi = ax.get_xlim()
        assert lo <= 0.0 and -lo < 0.5, ax.get_title()
        assert 8.0 < hi < 8.5, ax.get_title()


def test_a_single_sample_time_spans_0_to_its_time(drawn):
    fig = drawn([2.0])
    for ax in _used(fig):
        lo, hi = ax.get_xlim()
        assert lo <= 0.0 and 2.0 < hi < 2.2, ax.get_title()


def test_a_single_sample_time_shows_its_interval(drawn):
    fig = drawn([2.0])
    est = _estimates([2.0])[0]
    for k, name in enumerate(NAMES):
        ax = fig.axes[k]
        # the 90 % interval as an error bar at t = 2 h from q05 to q95 (a band over one time has no width)
        segs = [np.asarray(s) for c in ax.collections if hasattr(c, "get_segments") for s in c.get_segments()]
        bars = [s for s in segs if s.shape[0] == 2 and np.allclose(s[:, 0], 2.0) and np.ptp(s[:, 1]) > 0]
        assert bars, name
        assert np.allclose(sorted(bars[0][:, 1]), [est.q05[k], est.q95[k]]), name
    labels = [t.get_text() for lg in fig.legends + [ax.get_legend() for ax in fig.axes if ax.get_legend()]
              for t in lg.get_texts()]
    assert any("90 %" in x for x in labels)


def test_legend_sits_outside_the_panels(drawn):
    fig = drawn([0.5, 1, 2])
    fig.canvas.draw()
    assert all(ax.get_legend() is None for ax in fig.axes)
    assert len(fig.legends) == 1
    box = fig.legends[0].get_window_extent()
    assert not any(box.overlaps(ax.get_window_extent()) for ax in _used(fig))
