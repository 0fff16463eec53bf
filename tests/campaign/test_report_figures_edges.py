"""The campaign report's figures at the edges of a campaign: nothing logged yet, one logged interval,
one sample. Each figure is read as a matplotlib object (``_png`` replaced), not as pixels."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from bmctl import campaign as cp
from bmctl.campaign import db
from bmctl.campaign import html_report as hr
from bmctl.campaign.workflow import CAMPAIGN_FILTER, Campaign
from bmctl.measure.tables import ParticleTable

ROOT = Path(__file__).resolve().parents[2]
CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
RECIPE = ROOT / "controllers" / "recipe-300rpm-continuous.toml"
HOURS = 12.0


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    """c1: nothing logged; c2: one interval with a reading above the ceiling; c3: c2 and a sample."""
    base = tmp_path_factory.mktemp("report-figures")
    c1 = base / "c1"
    cp.init(c1, CARD, RECIPE, {"d50_um": 45.0}, hours=HOURS, temperature_max_c=60.0, particles=100,
            estimator={**CAMPAIGN_FILTER, "sigma_temperature_c": 5.0})
    c2 = base / "c2"
    shutil.copytree(c1, c2)
    cp.log(c2, rpm=300.0, hours=0.5, temperature_c=60.1)
    c3 = base / "c3"
    shutil.copytree(c2, c3)
    rng = np.random.default_rng(3)
    cp.sample(c3, 0.5, [ParticleTable.from_size_aspect(rng.lognormal(np.log(55.0), 0.4, 80),
                                                       rng.uniform(0.0, 0.15, 80))])
    return {"c1": c1, "c2": c2, "c3": c3}


def _prior(folder: Path) -> dict:
    """The card's prior as ``campaign init`` stored it (the estimate before anything is logged)."""
    c = Campaign(folder, read_only=True)
    try:
        return json.loads(c.con.execute("SELECT estimate FROM estimator_states WHERE t_h < 0").fetchone()[0])
    finally:
        c.close()


def _figures(folder: Path, monkeypatch) -> tuple[dict, hr.ReportData]:
    """The report's figures of ``folder`` as figure objects, by name."""
    c = Campaign(folder, read_only=True)
    try:
        with db.transaction(c.con, write=False, where=str(folder)):
            d = hr.ReportData(c)
    finally:
        c.close()
    figs: list = []
    monkeypatch.setattr(hr, "_png", lambda fig: figs.append(fig) or str(len(figs) - 1))
    out = {k: figs[int(v)] for k, v in hr.figures(d).items()}
    return out, d


@pytest.fixture
def close_figures():
    yield
    import matplotlib.pyplot as plt

    plt.close("all")


def _legend_texts(fig) -> list[str]:
    return [t.get_text() for lg in fig.legends for t in lg.get_texts()]


def _texts(ax) -> str:
    return " ".join(t.get_text() for t in ax.texts)


def _points(ax) -> list[tuple[float, float]]:
    """Every (x, y) drawn by the axes' lines (error bars' markers included)."""
    out = []
    for ln in ax.lines:
        x, y = np.asarray(ln.get_xdata(), dtype=float), np.asarray(ln.get_ydata(), dtype=float)
        out += [(a, b) for a, b in zip(x, y) if np.isfinite(a) and np.isfinite(b)]
    return out


def _interval_drawn(ax, t: float, lo: float, hi: float) -> bool:
    """Whether the axes shows the interval [lo, hi] at time t: an error bar there, or a band whose
    vertical extent at t covers it."""
    for coll in ax.collections:
        if hasattr(coll, "get_segments"):  # error bars (LineCollection)
            for seg in coll.get_segments():
                seg = np.asarray(seg)
                if seg.shape[0] == 2 and abs(seg[0, 0] - t) < 1e-9 and abs(seg[1, 0] - t) < 1e-9:
                    a, b = sorted(seg[:, 1])
                    if abs(a - lo) < 1e-6 * max(1, abs(lo)) and abs(b - hi) < 1e-6 * max(1, abs(hi)):
                        return True
        for path in coll.get_paths():
            v = path.vertices
            near = v[np.abs(v[:, 0] - t) < 1e-9]
            if near.size and near[:, 1].min() <= lo + 1e-9 and near[:, 1].max() >= hi - 1e-9 \
                    and np.ptp(v[:, 0]) > 0:
                return True
    return False


def test_before_any_log_every_estimate_panel_shows_the_prior_at_0_h(folders, monkeypatch, close_figures):
    figs, d = _figures(folders["c1"], monkeypatch)
    prior = _prior(folders["c1"])
    assert not d.nodes
    for ax, k in zip(figs["estimate"].axes, hr.QUANTITIES):
        assert any(abs(x) < 1e-9 and abs(y - prior[k]) < 1e-9 for x, y in _points(ax)), k
        assert _interval_drawn(ax, 0.0, prior[f"{k}_q05"], prior[f"{k}_q95"]), k
        lo, hi = ax.get_ylim()
        assert lo <= prior[f"{k}_q05"] and hi >= prior[f"{k}_q95"], k  # not a meaningless 0-1 range
        assert "nothing logged yet" in _texts(ax), k
        assert ax.get_ylabel(), k
    assert any("prior" in t for t in _legend_texts(figs["estimate"]))
    # the temperature estimate starts from the prior too
    tax = figs["temperature"].axes[0]
    assert any(abs(x) < 1e-9 and abs(y - prior["temperature_c"]) < 1e-9 for x, y in _points(tax))
    # the plan figure says why it is empty, on an rpm range of the mill
    pax = figs["actions"].axes[0]
    assert "nothing logged" in _texts(pax)
    assert pax.get_ylim()[1] > 1.0


@pytest.mark.parametrize("name", ["c2", "c3"])
def test_one_node_draws_its_interval(folders, monkeypatch, close_figures, name):
    figs, d = _figures(folders[name], monkeypatch)
    assert len({t for t, _ in d.nodes}) == 1
    t1, e1 = d.nodes[-1]
    for ax, k in zip(figs["estimate"].axes, hr.QUANTITIES):
        assert _interval_drawn(ax, t1, e1[f"{k}_q05"], e1[f"{k}_q95"]), k
        assert any(abs(x - t1) < 1e-9 and abs(y - e1[k]) < 1e-9 for x, y in _points(ax)), k
    tax = figs["temperature"].axes[0]
    assert _interval_drawn(tax, t1, e1["temperature_c_q05"], e1["temperature_c_q95"])


@pytest.mark.parametrize("name", ["c2", "c3"])
def test_temperature_series_show_and_only_drawn_ones_are_named(folders, monkeypatch, close_figures, name):
    figs, _ = _figures(folders[name], monkeypatch)
    tax = figs["temperature"].axes[0]
    mean_line = [ln for ln in tax.lines if ln.get_label() == "estimate (mean)"]
    assert mean_line and mean_line[0].get_marker() not in (None, "None", "", " ")
    labels = _legend_texts(figs["temperature"])
    assert "reading above the ceiling" in labels
    assert "reading" not in labels  # the only reading is above the ceiling: no empty series named
    for lab in labels:  # every named series holds data
        arts = [a for a in tax.lines + tax.collections + tax.containers if a.get_label() == lab]
        assert arts, lab


def test_temperature_title_gives_the_campaigns_reading_sigma(folders, monkeypatch, close_figures):
    figs, d = _figures(folders["c2"], monkeypatch)
    assert d.sigma_reading_c == 5.0
    title = figs["temperature"].axes[0].get_title()
    assert "σ 5 °C" in title and "σ 2 °C" not in title


@pytest.mark.parametrize("name", ["c1", "c2", "c3"])
def test_time_axes_cover_the_batch_with_room_for_end_markers(folders, monkeypatch, close_figures, name):
    figs, _ = _figures(folders[name], monkeypatch)
    for key in ("estimate", "actions", "temperature"):
        for ax in figs[key].axes:
            lo, hi = ax.get_xlim()
            assert lo < 0.0 < HOURS < hi, (key, lo, hi)
            assert hi - HOURS < 0.1 * HOURS and -lo < 0.1 * HOURS, (key, lo, hi)
            assert ax.get_xlabel() == "batch time (h)"


@pytest.mark.parametrize("name", ["c1", "c2", "c3"])
def test_legends_sit_outside_the_axes(folders, monkeypatch, close_figures, name):
    figs, _ = _figures(folders[name], monkeypatch)
    for key, fig in figs.items():
        fig.canvas.draw()
        assert all(ax.get_legend() is None for ax in fig.axes), key
        if not any(ax.get_legend_handles_labels()[0] for ax in fig.axes):
            assert not fig.legends, key  # nothing named: no empty legend
            continue
        assert len(fig.legends) == 1, key
        box = fig.legends[0].get_window_extent()
        for ax in fig.axes:
            if ax.get_visible():
                assert not box.overlaps(ax.get_window_extent()), key
