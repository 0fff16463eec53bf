"""design.png and the campaign report's figures, read as matplotlib objects (``savefig`` / ``_png``
replaced), not as pixels.

design.png: the predicted curves run through each segment as the moment model predicts it (they
were straight lines from one segment end to the next: a 4 h segment at 330 rpm drew the mean size
falling steadily, where the model has it rise by half and fall back); the rpm panel has its time
labels. The campaign report: the estimate's markers sit above the readings, the samples and the
prior, and are smaller than they are, so that both show where they nearly coincide; the plan
figure's rpm axis starts at 0 also where only plans are drawn.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from .campaign.test_report_figures_edges import _figures

ROOT = Path(__file__).resolve().parents[1]
CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
RECIPE = ROOT / "controllers" / "recipe-300rpm-continuous.toml"


@pytest.fixture
def close_figures():
    yield
    import matplotlib.pyplot as plt

    plt.close("all")


# --- design.png -----------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def model():
    from bmctl.moments.model import make_moment_model

    return make_moment_model(CARD)


def _design(model, segments, hours, target, with_model=True):
    """A Design of ``segments`` with the moment model's own prediction at the segment ends."""
    from bmctl.control.design import Design, simulate_segments

    X = np.array(simulate_segments(model, segments)[4])
    U = np.array([[r, 1.0 if r > 0 else 0.0] for _, r in segments])
    d = Design("card", "mpc", target, hours, 80.0, U, X, np.maximum(X[:-1, 4], X[1:, 4]), list(segments), None, None)
    if with_model:
        d.model = model  # as design_schedule leaves it
    return d


def _design_figure(monkeypatch, tmp_path, d):
    import bmctl.io
    from bmctl.control.design import design_figure

    figs = []
    monkeypatch.setattr(bmctl.io, "savefig", lambda fig, path, **kw: figs.append(fig))
    design_figure(d, tmp_path / "design.png")
    return figs[0]


def _line(fig, label):
    return next(ln for ax in fig.axes for ln in ax.get_lines() if ln.get_label() == label)


def _temperature(fig):
    """The predicted vial temperature (the first line of its panel)."""
    return next(ax for ax in fig.axes if ax.get_ylabel() == "vial temperature (°C)").get_lines()[0]


def _passes_through_the_segment_ends(line, t_end, y_end):
    x, y = np.asarray(line.get_xdata(), dtype=float), np.asarray(line.get_ydata(), dtype=float)
    for t, v in zip(t_end, y_end):
        i = np.flatnonzero(np.isclose(x, t, rtol=0, atol=1e-9))
        assert i.size and np.isclose(y[i[-1]], v, rtol=1e-12), (t, v)


def test_design_curves_follow_the_model_through_a_long_segment(model, monkeypatch, tmp_path, close_figures):
    """One 4 h segment at 330 rpm: the mean size rises from 40 µm to over 60 µm within the first
    hours and falls back; the figure drew one straight line from 40 to the end value."""
    d = _design(model, [(4.0, 330.0)], 4.0, {"s_mean_um": 30.0})
    fig = _design_figure(monkeypatch, tmp_path, d)
    line = _line(fig, "mean size s (µm, by number)")
    x, y = np.asarray(line.get_xdata(), dtype=float), np.asarray(line.get_ydata(), dtype=float)
    assert x.size > 50 and np.all(np.diff(x) > 0)
    _passes_through_the_segment_ends(line, d.times_h, d.X[:, 0])
    assert y.max() > 1.2 * max(d.X[0, 0], d.X[-1, 0])  # the rise the moment model predicts
    # a point within the segment is the model's own integration up to that time (its substeps of 1/16 h)
    i = int(np.argmin(np.abs(x - 1.0)))
    assert x[i] == pytest.approx(1.0)
    x1 = model.step(model.x0(), [330.0, 1.0], 1.0, substeps=16)
    assert y[i] == pytest.approx(float(x1[0]), rel=1e-6)
    temp = _temperature(fig)
    assert temp.get_label() == "vial temperature"  # not "at segment ends": the curve is the prediction
    ty = np.asarray(temp.get_ydata(), dtype=float)
    assert ty[i] == pytest.approx(float(x1[4]), rel=1e-6)
    assert ty[i] > d.X[0, 4] + (d.X[-1, 4] - d.X[0, 4]) / 4.0  # well above the straight line from end to end


def test_design_curves_hold_in_rests_and_meet_every_segment_end(model, monkeypatch, tmp_path, close_figures):
    """Milling, rest, a 6-min burst, rest, milling: the curves pass through every segment end (the
    rows of predicted.csv); within a rest the sizes hold and the vial cools."""
    segs = [(1.0, 400.0), (0.5, 0.0), (0.1, 400.0), (0.4, 0.0), (0.5, 300.0)]
    d = _design(model, segs, 3.0, {"d50_um": (60.0, 70.0)})
    fig = _design_figure(monkeypatch, tmp_path, d)
    t = d.times_h
    s_line, temp = _line(fig, "mean size s (µm, by number)"), _temperature(fig)
    for line, col in ((s_line, 0), (_line(fig, "std of size s (µm, by number)"), 1),
                      (_line(fig, "mean irregularity r"), 2), (temp, 4)):
        _passes_through_the_segment_ends(line, t, d.X[:, col])
    x = np.asarray(s_line.get_xdata(), dtype=float)
    for k in (1, 3):  # the rests
        inside = (x > t[k] + 1e-9) & (x < t[k + 1] - 1e-9)
        assert inside.sum() >= 3, k
        assert np.allclose(np.asarray(s_line.get_ydata())[inside], d.X[k, 0], rtol=1e-7), k
        ty = np.asarray(temp.get_ydata(), dtype=float)[(x >= t[k] - 1e-9) & (x <= t[k + 1] + 1e-9)]
        assert np.all(np.diff(ty) < 0), k


def test_design_figure_draws_the_plant_check(model, monkeypatch, tmp_path, close_figures):
    """The plant check was printed but not drawn: design.png showed the moment model alone. Its
    ensemble mean and range now stand at the schedule's end beside each curve it gives (labelled for a
    target), and its peak vial temperature as a line."""
    d = _design(model, [(2.0, 300.0), (1.0, 0.0)], 4.0, {"s_mean_um": 50.0})
    d.plant = {"seeds": 3, "particles": 500, "s_mean_um": {"mean": 51.0, "min": 49.5, "max": 52.5},
               "temperature_c": {"mean": 40.0, "min": 39.0, "max": 41.0}, "temperature_peak_c": 66.6}
    fig = _design_figure(monkeypatch, tmp_path, d)
    sizes = fig.axes[1]
    bars = [c for c in sizes.containers if c.get_label().startswith("plant check (3 plants)")]
    assert len(bars) == 1
    x, y = (np.asarray(v, dtype=float) for v in bars[0].lines[0].get_data())
    assert x.tolist() == [3.0] and y.tolist() == [51.0]  # at the schedule's end, the ensemble's mean
    seg = np.asarray(bars[0].lines[2][0].get_segments()[0], dtype=float)
    assert seg[:, 1].tolist() == [49.5, 52.5]  # its range
    peak = _line(fig, "plant check (3 plants): peak 66.6 °C")
    assert np.allclose(peak.get_ydata(), 66.6)
    assert "plant check" in fig._suptitle.get_text()
    d.plant = None  # no check: nothing drawn for it
    fig = _design_figure(monkeypatch, tmp_path, d)
    assert not fig.axes[1].containers and "plant check" not in fig._suptitle.get_text()


def test_design_without_its_model_marks_the_segment_ends(model, monkeypatch, tmp_path, close_figures):
    """Without the model only the segment ends are predicted: they are marked, and the temperature
    says so, instead of straight lines that read as the prediction between them."""
    d = _design(model, [(1.0, 300.0), (1.0, 0.0), (1.0, 300.0)], 3.0, {"s_mean_um": 50.0}, with_model=False)
    fig = _design_figure(monkeypatch, tmp_path, d)
    line = _line(fig, "mean size s (µm, by number)")
    assert line.get_marker() not in (None, "None", "", " ")
    assert len(line.get_xdata()) == len(d.times_h)
    temp = _line(fig, "vial temperature at segment ends")
    assert temp.get_marker() not in (None, "None", "", " ")


def test_design_rpm_panel_has_its_time_labels_off_the_legends(model, monkeypatch, tmp_path, close_figures):
    """The rpm panel, twice as wide as the panels below, had no time labels: a switch could not be read
    off it. Its labels show, below it and clear of the legends above the next row of panels."""
    d = _design(model, [(1.0, 300.0), (1.0, 0.0), (1.0, 300.0)], 4.0, {"d50_um": (60.0, 70.0), "span": 0.8})
    fig = _design_figure(monkeypatch, tmp_path, d)
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    rpm_ax = fig.axes[0]
    assert rpm_ax.get_ylabel() == "rpm"
    shown = [lab for lab in rpm_ax.get_xticklabels() if lab.get_visible() and lab.get_text()]
    lo, hi = rpm_ax.get_xlim()
    assert len([lab for lab in shown if lo <= lab.get_position()[0] <= hi]) >= 3
    boxes = [lab.get_window_extent(r) for lab in shown]
    for ax in fig.axes[1:]:
        leg = ax.get_legend()
        if leg is not None:
            lb = leg.get_window_extent(r)
            assert not any(b.overlaps(lb) for b in boxes)


def test_design_schedule_keeps_the_model_for_the_figure(model, monkeypatch, tmp_path, close_figures):
    """design_schedule leaves its model with the design; the figure then draws within each segment."""
    from bmctl.control import load_controller
    from bmctl.control.design import design_schedule

    cfg = load_controller(ROOT / "controllers" / "mpc-default.toml")
    d = design_schedule(model, {"s_mean_um": 45.0}, 1.0, cfg, local=False)
    assert d.model is model
    fig = _design_figure(monkeypatch, tmp_path, d)
    line = _line(fig, "mean size s (µm, by number)")
    assert len(line.get_xdata()) > len(d.times_h) + 10
    _passes_through_the_segment_ends(line, d.times_h, d.X[:, 0])


# --- the campaign report --------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def campaigns(tmp_path_factory):
    """one: one logged interval with a reading and a sample at its end; feed: a sample at 0 h only,
    then an advice (nothing logged)."""
    from bmctl import campaign as cp
    from bmctl.campaign.workflow import CAMPAIGN_FILTER
    from bmctl.measure.tables import ParticleTable

    base = tmp_path_factory.mktemp("report-markers")
    start = base / "start"
    cp.init(start, CARD, RECIPE, {"d50_um": 45.0}, hours=12.0, particles=100, estimator=dict(CAMPAIGN_FILTER))
    rng = np.random.default_rng(5)
    table = ParticleTable.from_size_aspect(rng.lognormal(np.log(50.0), 0.4, 80), rng.uniform(0.0, 0.15, 80))
    one = base / "one"
    shutil.copytree(start, one)
    cp.log(one, rpm=300.0, hours=0.5, temperature_c=34.0)
    cp.sample(one, 0.5, [table])
    feed = base / "feed"
    shutil.copytree(start, feed)
    cp.sample(feed, 0.0, [table])
    cp.advise(feed)
    return {"one": one, "feed": feed}


def _markers(ax) -> list[tuple[str, object]]:
    """(label, Line2D) of every line with a marker; an error bar's markers under its container's label."""
    out = []
    bars = {}
    for c in ax.containers:
        if getattr(c, "lines", None) and c.lines[0] is not None:
            bars[id(c.lines[0])] = c.get_label()
    for ln in ax.get_lines():
        if ln.get_marker() not in (None, "None", "", " "):
            out.append((bars.get(id(ln), ln.get_label()), ln))
    return out


def _at(ln, t: float) -> bool:
    return bool(np.any(np.isclose(np.asarray(ln.get_xdata(), dtype=float), t, rtol=0, atol=1e-9)))


def _shows_over(est, other) -> bool:
    """Whether estimate marker ``est`` and ``other`` at the same point both show: the estimate drawn
    above and smaller (the other's rim shows around it)."""
    return est.get_zorder() > other.get_zorder() and est.get_markersize() < other.get_markersize()


def _check_estimate_over(ax, t: float, others: tuple[str, ...]) -> int:
    marks = _markers(ax)
    est = [ln for lab, ln in marks if lab.startswith("estimate") and _at(ln, t)]
    oth = [ln for lab, ln in marks if lab.startswith(others) and _at(ln, t)]
    assert est, [lab for lab, _ in marks]
    for e in est:
        for o in oth:
            assert _shows_over(e, o), (e.get_label(), o.get_label(), e.get_zorder(), o.get_zorder())
    return len(oth)


def test_report_estimate_shows_over_the_sample_and_the_reading(campaigns, monkeypatch, close_figures):
    """After one logged interval with a reading and a sample at its end, the estimate's dot at 0.5 h sat
    under the sample's cross and under the reading's disc (same zorder, drawn later)."""
    figs, d = _figures(campaigns["one"], monkeypatch)
    t1 = d.nodes[-1][0]
    for ax in figs["estimate"].axes:
        assert _check_estimate_over(ax, t1, ("sample statistic",)) == 1, ax.get_title()
    tax = figs["temperature"].axes[0]
    assert _check_estimate_over(tax, t1, ("reading",)) == 1
    reading = next(ln for lab, ln in _markers(tax) if lab.startswith("reading"))
    assert reading.get_markerfacecolor() == "none"  # a ring: the estimate inside it shows whole


def test_report_feed_sample_shows_the_estimate_over_the_prior(campaigns, monkeypatch, close_figures):
    """A sample at 0 h only: the prior's square (filled white, drawn above) hid the estimate at 0 h
    where the sample leaves it unchanged (the vial temperature)."""
    figs, d = _figures(campaigns["feed"], monkeypatch)
    assert {t for t, _ in d.nodes} == {0.0}
    for ax in figs["estimate"].axes:
        assert _check_estimate_over(ax, 0.0, ("prior", "sample statistic")) == 2, ax.get_title()
    tax = figs["temperature"].axes[0]
    assert _check_estimate_over(tax, 0.0, ("prior",)) == 1
    for ax in list(figs["estimate"].axes) + [tax]:
        for lab, ln in _markers(ax):
            if lab.startswith("prior"):
                assert ln.get_markerfacecolor() == "none", lab


def test_report_plan_axis_starts_at_0_rpm_with_only_a_plan(campaigns, monkeypatch, close_figures):
    """Nothing logged, one advice at 300 rpm: the rpm axis ran 285-315, hiding that 0 is a rest."""
    figs, d = _figures(campaigns["feed"], monkeypatch)
    assert not d.actions and d.plans
    ax = figs["actions"].axes[0]
    lo, hi = ax.get_ylim()
    top = max(r["rpm"] for r in d.plans[0]["advice"]["schedule"])
    assert lo == 0.0 and top < hi <= 1.1 * top
