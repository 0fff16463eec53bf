"""Figures at their edges: narrow size ranges, one row of panels, short batches, a design with
rests and a span target, the reference histograms, a cropped overlay, a one-seed what-if.

Each figure is built with ``savefig`` replaced, and its axes, labels, legends and texts checked
on the figure object (drawn once where a position on the canvas is what matters)."""

from types import SimpleNamespace

import numpy as np
import pytest

from bmctl import plots


def _close(fig):
    import matplotlib.pyplot as plt

    plt.close(fig)


def _capture(monkeypatch, module, name="savefig"):
    figs = []
    monkeypatch.setattr(module, name, lambda fig, path, **kw: figs.append(fig))
    return figs


def _labels(axis):
    """The tick labels shown inside the axis range (drawn first)."""
    axis.figure.canvas.draw()
    lo, hi = sorted(axis.get_view_interval())
    return [t.get_text() for t, v in zip(axis.get_majorticklabels(), axis.get_majorticklocs())
            if t.get_text() and lo <= v <= hi]


def _overlaps(a, b) -> bool:
    return a.x0 < b.x1 and b.x0 < a.x1 and a.y0 < b.y1 and b.y0 < a.y1


# --- the log size axis --------------------------------------------------------------------------------

@pytest.mark.parametrize("lo, hi", [(30.5, 47.5), (26.0, 55.0), (38.0, 42.0), (7.0, 250.0), (0.5, 3000.0)])
def test_log_size_axis_labels_at_least_two_ticks_as_plain_numbers(lo, hi):
    """A narrow range (3 particles of 40 µm against a rest's prediction: 30-48 µm) showed no size
    label at all, a 25-55 µm one only "50": the fixed 1-2-5 ticks missed it."""
    plt = plots.plt
    fig, ax = plt.subplots()
    ax.plot([lo, hi], [0, 1])
    ax.set_xscale("log")
    plots.log_size_axis(ax)
    ax.set_xlim(lo, hi)  # after: the ticks follow the range they are drawn with
    labels = _labels(ax.xaxis)
    assert len(labels) >= 2, labels
    for text in labels:  # plain numbers, no powers of ten
        float(text.replace("−", "-"))
    _close(fig)


# --- size_pdf.png ---------------------------------------------------------------------------------------

def _size_pdf(monkeypatch, tmp_path, times_h, d50_um):
    figs = _capture(monkeypatch, plots)
    edges = np.arange(0.0, 301.0)
    c = 0.5 * (edges[1:] + edges[:-1])
    p_s = np.array([np.exp(-0.5 * (np.log(np.maximum(c, 0.5) / (40.0 * (1 + t))) / 0.35) ** 2) for t in times_h])
    p_s /= p_s.sum(axis=1, keepdims=True)
    plots.size_distributions(tmp_path / "p.png", edges, p_s, times_h, d50_um, "t")
    return figs[0]


def test_size_pdf_legend_clears_the_axis_labels_in_one_row(monkeypatch, tmp_path):
    """With one row of panels (a batch up to 2 h) the figure legend was drawn over the x-axis label."""
    fig = _size_pdf(monkeypatch, tmp_path, [0.0, 1.0, 2.0], [41.0, 132.0, 124.0])
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    leg = fig.legends[0].get_window_extent(r)
    shown = [a for a in fig.axes if a.get_visible() and a.get_xlabel()]
    assert shown
    for a in shown:
        assert not _overlaps(leg, a.xaxis.label.get_window_extent(r))
        for t in a.get_xticklabels():
            if t.get_text():
                assert not _overlaps(leg, t.get_window_extent(r))
    _close(fig)


def test_size_pdf_d50_text_stays_inside_its_panel(monkeypatch, tmp_path):
    """"D50 132 µm" beside a line near the right edge ran past the panel."""
    fig = _size_pdf(monkeypatch, tmp_path, [0.0, 1.0, 2.0], [41.0, 132.0, 250.0])
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    texts = [(a, t) for a in fig.axes for t in a.texts if t.get_text().startswith(("D50", " D50"))]
    assert len(texts) == 3
    for a, t in texts:
        box, frame = t.get_window_extent(r), a.get_window_extent(r)
        assert frame.x0 - 0.5 <= box.x0 and box.x1 <= frame.x1 + 0.5, t.get_text()
    _close(fig)


@pytest.mark.parametrize("times_h", [[0.0, 0.0833], [0.0, 1.0, 2.0], [0.0, 0.5, 1.0, 1.5, 2.0]])
def test_size_pdf_right_axis_labelled_on_the_last_panel_of_each_row(monkeypatch, tmp_path, times_h):
    """With two panels the label sat on the hidden third one: no panel named the right axis."""
    fig = _size_pdf(monkeypatch, tmp_path, times_h, [50.0] * len(times_h))
    twins = [a for a in fig.axes if a.get_visible() and a.yaxis.get_label_position() == "right"]
    labelled = [a for a in twins if a.get_ylabel() == "cumulative volume (%)"]
    nrow = int(np.ceil(len(times_h) / min(3, len(times_h))))
    assert len(labelled) == nrow
    for a in labelled:  # the rightmost drawn panel of its row
        row = [b for b in twins if abs(b.get_position().y0 - a.get_position().y0) < 1e-6]
        assert a.get_position().x1 == max(b.get_position().x1 for b in row)
    for a in fig.axes:  # every drawn panel's size axis says µm somewhere below it
        if a.get_visible() and a.get_xlabel():
            assert "µm" in a.get_xlabel() and "um" not in a.get_xlabel().replace("µm", "")
    _close(fig)


# --- size_heatmap.png -----------------------------------------------------------------------------------

def test_heatmap_legends_are_off_the_maps(monkeypatch, tmp_path):
    """The volume map's legend covered its D90 line in a short run."""
    figs = _capture(monkeypatch, plots)
    edges = np.geomspace(1.0, 1000.0, 61)
    centres = np.sqrt(edges[1:] * edges[:-1])
    t = [0.0, 0.0833]
    p_s = np.array([np.exp(-0.5 * (np.log(centres / 40.0) / 0.1) ** 2) for _ in t])
    p_s /= p_s.sum(axis=1, keepdims=True)
    cols = {"s_mean_um": np.array([40.0, 41.0]), "d10_um": np.array([36.0, 36.0]),
            "d50_um": np.array([41.0, 42.0]), "d90_um": np.array([46.0, 59.0])}
    plots.size_heatmap(tmp_path / "h.png", edges, p_s, t, cols, "t")
    fig = figs[0]
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    maps = fig.axes[:2]
    for ax in maps:
        leg = ax.get_legend()
        assert leg is not None and not _overlaps(leg.get_window_extent(r), ax.get_window_extent(r))
        assert not _overlaps(leg.get_window_extent(r), ax.xaxis.label.get_window_extent(r))
    assert [x.get_text() for x in maps[1].get_legend().get_texts()] == ["D10", "D50", "D90"]
    assert len(_labels(maps[0].yaxis)) >= 2
    _close(fig)


# --- design.png -----------------------------------------------------------------------------------------

def _design(segments, hours, target):
    from bmctl.control.design import Design

    t = np.concatenate([[0.0], np.cumsum([h for h, _ in segments])])
    s_mean = np.linspace(40.0, 55.0, t.size)
    X = np.column_stack([s_mean, np.linspace(4.0, 20.0, t.size), np.linspace(0.02, 0.05, t.size),
                         np.linspace(0.02, 0.08, t.size), np.linspace(25.0, 40.0, t.size), np.zeros(t.size)])
    U = np.array([[r, 1.0 if r > 0 else 0.0] for _, r in segments])
    return Design("card", "mpc", target, hours, 80.0, U, X, np.full(len(segments), 40.0), list(segments), None, None)


def _design_figure(monkeypatch, tmp_path, d):
    import bmctl.io

    from bmctl.control.design import design_figure

    figs = _capture(monkeypatch, bmctl.io)
    design_figure(d, tmp_path / "design.png")
    return figs[0]


def _legend_texts(fig):
    return [t.get_text() for ax in fig.axes if ax.get_legend() for t in ax.get_legend().get_texts()]


def test_design_figure_says_um_and_draws_the_span_with_its_target(monkeypatch, tmp_path):
    """Legends said "s_mean_um", "d50_um"; a span target and the predicted span were not drawn."""
    d = _design([(0.5, 260.0), (0.5, 0.0), (0.4, 240.0)], 2.0, {"d50_um": (60.0, 70.0), "span": 0.8})
    fig = _design_figure(monkeypatch, tmp_path, d)
    texts = _legend_texts(fig)
    assert not [s for s in texts if "_um" in s or " um" in s], texts
    assert plots.quantity_label("d50_um") in texts and plots.quantity_label("s_mean_um") in texts
    assert any("target window" in s and "D50 (µm" in s for s in texts)
    span_ax = [ax for ax in fig.axes if "span" in ax.get_ylabel()]
    assert len(span_ax) == 1
    ax = span_ax[0]
    assert "µm" not in ax.get_ylabel()
    lines = [ln.get_label() for ln in ax.get_lines()]
    assert "predicted span" in lines and "target span" in lines
    target = [ln for ln in ax.get_lines() if ln.get_label() == "target span"][0]
    assert np.allclose(target.get_ydata(), 0.8)
    _close(fig)


def test_design_figure_time_axis_is_the_batch_and_legends_are_off_the_data(monkeypatch, tmp_path):
    """The time axis ended where the schedule's last segment ended (1.4 h of a 2 h batch) and the
    size legend covered the D50 window."""
    d = _design([(0.5, 260.0), (0.5, 0.0), (0.4, 240.0)], 2.0, {"d50_um": (60.0, 70.0)})
    fig = _design_figure(monkeypatch, tmp_path, d)
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    for ax in fig.axes:
        assert ax.get_xlim() == pytest.approx((0.0, 2.0))
        leg = ax.get_legend()
        if leg is not None:
            assert not _overlaps(leg.get_window_extent(r), ax.get_window_extent(r))
    xlabels = [ax.get_xlabel() for ax in fig.axes if ax.get_xlabel()]
    assert xlabels and all(x == "batch time t (h)" for x in xlabels)
    # the docstring's "rests shaded": the rest 0.5-1.0 h, and the stopped mill after 1.4 h, in every panel
    rpm_ax = fig.axes[0]
    assert "rest (rpm 0)" in _legend_texts(fig)
    spans = [p for p in rpm_ax.patches if p.get_label() == "rest (rpm 0)"]
    assert len(spans) == 1 and spans[0].get_x() == pytest.approx(0.5) and spans[0].get_width() == pytest.approx(0.5)
    _close(fig)


def test_design_figure_rpm_axis_starts_at_0(monkeypatch, tmp_path):
    """One constant segment: the rpm axis ran 133-147, hiding that 0 is a rest."""
    d = _design([(4.0, 140.0)], 4.0, {"d50_um": 60.0})
    fig = _design_figure(monkeypatch, tmp_path, d)
    rpm_ax = fig.axes[0]
    assert rpm_ax.get_ylabel() == "rpm"
    lo, hi = rpm_ax.get_ylim()
    assert lo == 0.0 and hi > 140.0
    _close(fig)


# --- reference.png --------------------------------------------------------------------------------------

def test_reference_figure_labels_both_axes_and_the_cut(monkeypatch, tmp_path):
    """Unlabelled y axes, r called "aspect ratio r", the 99.5 % cut of the x range unsaid."""
    import bmctl.io
    from bmctl.validation.report import reference_figure

    figs = _capture(monkeypatch, bmctl.io)
    rng = np.random.default_rng(0)
    cmp = SimpleNamespace(card="card", hours=0.25, particles=500, seeds=(0, 1),
                          plant_s=[rng.lognormal(3.7, 0.3, 300)], ref_s=[rng.lognormal(3.7, 0.3, 300)],
                          plant_r=[rng.uniform(0, 0.3, 300)], ref_r=[rng.uniform(0, 0.3, 300)],
                          ks={"s": (0.03, 0.5), "r": (0.04, 0.6)})
    reference_figure(SimpleNamespace(reference=[cmp]), tmp_path / "reference.png")
    fig = figs[0]
    s_ax, r_ax = fig.axes
    assert s_ax.get_ylabel() == "density (1/µm)"
    assert r_ax.get_ylabel().startswith("density") and "µm" not in r_ax.get_ylabel()
    assert "µm" in s_ax.get_xlabel()
    assert plots.R_LABEL in r_ax.get_xlabel() and "aspect" not in r_ax.get_xlabel()
    for ax in (s_ax, r_ax):
        assert "99.5 % of particles shown" in ax.get_xlabel()
    _close(fig)


# --- the measure overlay --------------------------------------------------------------------------------

def test_overlay_shades_what_the_crop_left_out(monkeypatch, tmp_path):
    """The overlay of a cropped measurement showed the whole image unshaded."""
    from bmctl.measure import overlay

    figs = _capture(monkeypatch, overlay)
    image = np.full((60, 80), 0.5)
    labels = np.zeros((20, 30), dtype=int)
    labels[5:15, 5:15] = 1
    overlay.write_overlay(tmp_path / "o.png", image, labels, (10, 40), crop="10:30,40:70")
    rgb = np.asarray(figs[0].axes[0].images[0].get_array())
    inside, outside = rgb[20, 42], rgb[50, 5]
    assert np.allclose(inside, 0.5)  # gray: measured
    assert outside[0] > outside[1] + 0.2 and outside[1] == pytest.approx(outside[2])  # red: left out
    assert np.allclose(rgb[5, 50], outside) and np.allclose(rgb[20, 75], outside)
    _close(figs[0])


def test_measure_passes_its_crop_to_the_overlay(monkeypatch, tmp_path):
    from bmctl.cli import main
    from bmctl.measure import overlay

    from ..conftest import ROOT

    seen = []
    monkeypatch.setattr(overlay, "write_overlay", lambda *a, **kw: seen.append(kw))
    rc = main(["measure", str(ROOT / "examples" / "micrograph-2h.tif"), "--crop", "175:250,670:745",
               "--out", str(tmp_path / "d" / "one.csv")])
    assert rc == 0
    assert len(seen) == 1 and seen[0]["crop"] == "175:250,670:745"


# --- whatif_moments.png ---------------------------------------------------------------------------------

@pytest.mark.parametrize("seeds", [1, 3])
def test_whatif_title_says_one_plant_without_a_band(monkeypatch, tmp_path, seeds):
    from bmctl import io, whatif

    figs = _capture(monkeypatch, io)
    t = np.linspace(0.0, 1.0, 5)
    res = whatif.WhatIfResult("a", t, {k: np.tile(np.linspace(1.0, 2.0, 5), (seeds, 1)) for k in whatif.KEYS},
                              np.full(10, 40.0), np.full(10, 0.05), 1.0, 1.0, np.full(seeds, 40.0))
    whatif._moments_figure([res], tmp_path / "m.png")
    title = figs[0]._suptitle.get_text()
    if seeds == 1:
        assert "one plant" in title and "band" in title and "90 %" not in title
    else:
        assert "90 % band" in title and "one plant" not in title
    _close(figs[0])
