"""trial.png at its edges: a target on a D-value (no column of trajectory.csv) gets a panel with its
target window; a window target is named in the legend; every time axis spans 0 to the batch end; a
trial of one interval draws its single points with markers and its bands as error bars, its rest
bar inside the interval; the legends sit above the data, not over it."""

import json

import numpy as np
import pytest
from matplotlib.container import ErrorbarContainer

from bmctl import io
from bmctl.plots import quantity_label
from bmctl.scenario import Scenario
from bmctl.trial import figures, trajectory_header

HALF_HOURS = [0.5, 1.0, 1.5, 2.0]


def _row(k: int, t_h: float) -> dict:
    """A made-up trajectory row: sizes in µm, r, temperatures, γ and δ with wide 90 % bands."""
    row = dict.fromkeys(trajectory_header(), 1.0)
    row.update(step=k, t_h=t_h, rpm=300.0 - 50 * k, milling=0.5, solver_status=0)
    for pre, q in (("true_", ""), ("est_", "")):
        row.update({f"{pre}s_mean_um{q}": 40.0 + k, f"{pre}s_std_um{q}": 12.0, f"{pre}r_mean{q}": 0.02,
                    f"{pre}r_std{q}": 0.04, f"{pre}temperature_c{q}": 30.0 + k})
    row.update(true_peak_temperature_c=40.0 - k)
    for key, (lo, hi) in {"s_mean_um": (35.0, 50.0), "s_std_um": (9.0, 16.0), "r_mean": (0.01, 0.05),
                          "r_std": (0.02, 0.06), "temperature_c": (28.0, 36.0)}.items():
        row[f"est_{key}_q05"], row[f"est_{key}_q95"] = lo, hi
    for key in ("gamma_mult", "delta_mult"):  # bands over the whole range: a legend anywhere inside covers them
        row[f"est_{key}"], row[f"est_{key}_q05"], row[f"est_{key}_q95"] = 1.0 + 0.05 * k, 0.5, 2.0
    return row


def _draw(tmp_path, monkeypatch, times, target=None, hours=None, final_true=None):
    header = trajectory_header()
    lines = [",".join(header)] + [",".join(str(_row(k, t)[h]) for h in header) for k, t in enumerate(times)]
    traj = tmp_path / "trajectory.csv"
    traj.write_text("\n".join(lines) + "\n", encoding="utf-8")
    if final_true is not None:
        (tmp_path / "summary.json").write_text(json.dumps({"final_true": final_true}), encoding="utf-8")
    sc = Scenario.model_validate({"scenario": {"name": "n", "description": "d"}, "model": "m.toml",
                                  "controller": {"config": "c.toml"}, "hours": hours or times[-1],
                                  "target": target or {}})
    figs = []
    monkeypatch.setattr(io, "savefig", lambda fig, path, **kw: figs.append(fig))
    figures(sc, traj, tmp_path, 80.0)
    assert len(figs) == 1
    return figs[0]


@pytest.fixture(autouse=True)
def _close_figures():
    yield
    import matplotlib.pyplot as plt

    plt.close("all")


def _panel(fig, title_start: str):
    found = [ax for ax in fig.axes if ax.get_title().startswith(title_start)]
    assert len(found) == 1, [ax.get_title() for ax in fig.axes]
    return found[0]


def _legend_texts(ax) -> list[str]:
    leg = ax.get_legend()
    return [] if leg is None else [t.get_text() for t in leg.get_texts()]


def _time_axes(fig):
    """The panels with a time axis (the rest-fraction twin shares the rpm panel's)."""
    return [ax for ax in fig.axes if ax.get_xlabel() == "batch time (h)"]


def test_d50_target_has_its_panel_with_estimate_plant_and_window(tmp_path, monkeypatch):
    fig = _draw(tmp_path, monkeypatch, HALF_HOURS, target={"d50_um": [55.0, 65.0]},
                final_true={"d50_um": 49.8, "s_mean_um": 43.0})
    ax = _panel(fig, quantity_label("d50_um"))
    assert "µm" in ax.get_ylabel() and ax.get_xlabel() == "batch time (h)"
    texts = _legend_texts(ax)
    assert any(t.startswith("estimate") and "no D50" in t for t in texts), texts  # drawn from the mean and std
    assert any(t.startswith("plant at batch end") for t in texts), texts
    assert "target window" in texts
    est = [ln for ln in ax.lines if ln.get_label().startswith("estimate")][0]
    assert np.allclose(est.get_xdata(), HALF_HOURS) and np.all(np.isfinite(est.get_ydata()))
    assert 40.0 < float(np.min(est.get_ydata())) < 60.0  # a D50 of a 40-43 µm mean, 12 µm std powder
    plant = [ln for ln in ax.lines if ln.get_label().startswith("plant")][0]
    assert list(plant.get_xdata()) == [2.0] and list(plant.get_ydata()) == [49.8]
    assert plant.get_marker() not in (None, "", "None")
    window = [p for p in ax.patches if p.get_label() == "target window"]
    assert len(window) == 1
    ys = window[0].get_path().transformed(window[0].get_patch_transform()).vertices[:, 1]
    assert (min(ys), max(ys)) == pytest.approx((55.0, 65.0))
    assert ax.get_xlim() == pytest.approx((0.0, 2.0))
    for title in ("mean size", "std of size", "mean irregularity"):  # the moments are still drawn
        _panel(fig, title)


def test_span_target_without_summary_still_draws_the_estimate(tmp_path, monkeypatch):
    fig = _draw(tmp_path, monkeypatch, HALF_HOURS, target={"span": 1.2})
    ax = _panel(fig, quantity_label("span"))
    texts = _legend_texts(ax)
    assert "target" in texts and any("no span" in t for t in texts), texts
    assert not any(t.startswith("plant") for t in texts)  # no summary.json: nothing claimed for the plant


def test_window_target_is_named_in_the_legend(tmp_path, monkeypatch):
    fig = _draw(tmp_path, monkeypatch, HALF_HOURS, target={"s_mean_um": [44.0, 48.0]})
    ax = _panel(fig, quantity_label("s_mean_um"))
    assert "target window" in _legend_texts(ax)
    assert {"plant (truth)", "estimate", "90 % band"} <= set(_legend_texts(ax))


def test_every_time_axis_spans_zero_to_the_batch_end(tmp_path, monkeypatch):
    fig = _draw(tmp_path, monkeypatch, HALF_HOURS)
    axes = _time_axes(fig)
    assert len(axes) == 6
    for ax in axes:
        assert ax.get_xlim() == pytest.approx((0.0, 2.0)), ax.get_title()


def test_single_interval_is_drawn_visibly(tmp_path, monkeypatch):
    t_end = 0.08334
    fig = _draw(tmp_path, monkeypatch, [t_end], target={"s_mean_um": 45.0})
    for ax in _time_axes(fig):
        assert ax.get_xlim() == pytest.approx((0.0, t_end)), ax.get_title()
    for title in ("mean size", "std of size", "mean irregularity"):
        ax = _panel(fig, title)
        drawn = {ln.get_label(): ln for ln in ax.lines}
        for label in ("plant (truth)", "estimate"):
            assert drawn[label].get_marker() not in (None, "", "None"), (title, label)
        assert any(isinstance(c, ErrorbarContainer) for c in ax.containers), title  # the 90 % band
    ax = _panel(fig, "estimated bonding")
    marked = [ln for ln in ax.lines if ln.get_marker() not in (None, "", "None") and len(ln.get_xdata()) == 1]
    assert len(marked) == 2  # γ and δ
    assert sum(isinstance(c, ErrorbarContainer) for c in ax.containers) == 2
    rpm = _panel(fig, "rpm")
    twin = [a for a in fig.axes if a.get_ylabel() == "rest fraction"][0]
    for bar in twin.patches:  # the rest bar lies inside the one interval
        assert bar.get_x() >= 0.0 and bar.get_x() + bar.get_width() <= t_end + 1e-12
    assert rpm.get_xlim() == pytest.approx((0.0, t_end))


@pytest.mark.parametrize("title", ["estimated bonding", "vial temperature", "mean size"])
def test_legend_sits_above_the_data(tmp_path, monkeypatch, title):
    fig = _draw(tmp_path, monkeypatch, HALF_HOURS)
    ax = _panel(fig, title)
    leg = ax.get_legend()
    assert leg is not None
    renderer = fig.canvas.get_renderer()
    bottom = ax.transData.inverted().transform(leg.get_window_extent(renderer))[0, 1]
    top_of_data = max(float(np.nanmax(a.get_datalim(ax.transData).y1)) if hasattr(a, "get_datalim") else
                      float(np.nanmax(a.get_ydata())) for a in ax.lines + ax.collections)
    assert bottom > top_of_data


def test_the_plant_curves_start_at_t0_where_trial_json_has_the_start(tmp_path, monkeypatch):
    """trajectory.csv has rows at interval ends only, so the plant's curves began at the first one (a
    trial's first half hour, where the powder grows most, was missing); trial.json now keeps the
    plant's state at t = 0 and the truth starts there. The estimate still starts at the first row;
    a trial.json without a start (an earlier bmctl's) draws as before."""
    start = {"s_mean_um": 37.0, "s_std_um": 4.0, "r_mean": 0.01, "r_std": 0.01, "temperature_c": 25.0,
             "peak_temperature_c": 25.0}
    (tmp_path / "trial.json").write_text(json.dumps({"scenario": "x", "seed": 0, "start": start}), encoding="utf-8")
    fig = _draw(tmp_path, monkeypatch, HALF_HOURS)
    size = _panel(fig, quantity_label("s_mean_um"))
    lines = {ln.get_label(): ln for ln in size.get_lines()}
    x, y = (np.asarray(v, dtype=float) for v in lines["plant (truth)"].get_data())
    assert x.tolist() == [0.0] + HALF_HOURS and y[0] == 37.0 and y[1:].tolist() == [40.0, 41.0, 42.0, 43.0]
    assert np.asarray(lines["estimate"].get_xdata(), dtype=float).tolist() == HALF_HOURS
    temp = _panel(fig, "vial temperature")
    pts = next(ln for ln in temp.get_lines() if ln.get_label().startswith("plant at interval ends"))
    assert np.asarray(pts.get_xdata(), dtype=float)[0] == 0.0 and np.asarray(pts.get_ydata())[0] == 25.0
    (tmp_path / "trial.json").write_text(json.dumps({"scenario": "x", "seed": 0}), encoding="utf-8")
    fig = _draw(tmp_path, monkeypatch, HALF_HOURS)
    size = _panel(fig, quantity_label("s_mean_um"))
    truth = next(ln for ln in size.get_lines() if ln.get_label() == "plant (truth)")
    assert np.asarray(truth.get_xdata(), dtype=float).tolist() == HALF_HOURS


def test_start_truth_is_the_plants_state_and_draws_nothing():
    """trial.json's start is the plant's moments at t = 0 (its peak: the temperature then), read
    without a draw from the plant's generator, so a trial's numbers do not change."""
    from bmctl.config import load_card
    from bmctl.plant.plant import Plant
    from bmctl.trial import TRUE_KEYS, start_truth

    from ..conftest import ROOT

    plant = Plant(load_card(ROOT / "models" / "alni-1to1-300rpm-lab.toml"), np.random.default_rng(3), 500)
    before = plant.rng.bit_generator.state
    st = start_truth(plant)
    assert set(st) == set(TRUE_KEYS)
    assert st["s_mean_um"] == pytest.approx(float(np.mean(plant.s)) * 1e6, rel=1e-12)
    assert st["peak_temperature_c"] == st["temperature_c"] == pytest.approx(plant.temperature_C)
    assert plant.rng.bit_generator.state == before
