"""size_heatmap.png: the time axis is the batch, 0 to its end (cells centred on the records
reached half a record step before 0 and past the end)."""

import numpy as np
import pytest

from bmctl import plots


def _figure(monkeypatch, tmp_path, times_h):
    figs = []
    monkeypatch.setattr(plots, "savefig", lambda fig, path, **kw: figs.append(fig))
    edges = np.geomspace(1.0, 1000.0, 61)
    centres = np.sqrt(edges[1:] * edges[:-1])
    p_s = np.array([np.exp(-0.5 * (np.log(centres / (40.0 * (1 + t))) / 0.3) ** 2) for t in times_h])
    p_s /= p_s.sum(axis=1, keepdims=True)
    grows = 40.0 * (1 + np.asarray(times_h))
    plots.size_heatmap(tmp_path / "h.png", edges, p_s, times_h, {"s_mean_um": grows, "d50_um": grows}, "t")
    assert len(figs) == 1
    return figs[0]


@pytest.mark.parametrize("times_h", [[0.0, 0.5], [0.0, 0.25, 0.5, 1.0, 2.0]])
def test_heatmap_time_axis_runs_from_0_to_the_batch_end(monkeypatch, tmp_path, times_h):
    fig = _figure(monkeypatch, tmp_path, times_h)
    for ax in fig.axes[:2]:  # the number and volume maps (the others are colour bars)
        assert ax.get_xlim() == pytest.approx((0.0, times_h[-1]))
        mesh = ax.collections[0].get_coordinates()[..., 0]
        assert mesh.min() == pytest.approx(0.0) and mesh.max() == pytest.approx(times_h[-1])
    import matplotlib.pyplot as plt

    plt.close(fig)
