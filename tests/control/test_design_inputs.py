"""`bmctl design`: inputs refused in one line before anything runs (the sweep, the batch length, the
ceiling against the card), the outputs written as one set, and what the summary says of the schedule."""

from __future__ import annotations

import numpy as np
import pytest

from bmctl.cli import main

from ..conftest import ROOT

CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
DEFAULT = (ROOT / "controllers" / "mpc-default.toml").read_text(encoding="utf-8")


def _controller(tmp_path, extra: str = "", **replace) -> str:
    """mpc-default.toml with ``replace`` ({old line start: new line}) and ``extra`` tables appended."""
    lines = DEFAULT.splitlines()
    for start, new in replace.items():
        lines = [new if ln.startswith(start) else ln for ln in lines]
    path = tmp_path / "c.toml"
    path.write_text("\n".join(lines) + "\n" + extra, encoding="utf-8")
    return str(path)


def _refused(capsys, args, out) -> str:
    """Run ``bmctl design`` expecting exit 2 with one line and nothing written; returns the line."""
    rc = main(["design", str(CARD), *args, "--plant-seeds", "0", "--out", str(out)])
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert rc == 2, err
    assert len(lines) == 1 and lines[0].startswith("bmctl: error: "), err
    assert "Traceback" not in err
    assert not out.exists()
    return lines[0]


@pytest.mark.parametrize("objective", [[], ["--objective", "min_energy"]])
def test_an_empty_sweep_is_refused_naming_the_field(tmp_path, capsys, objective):
    ctrl = _controller(tmp_path, '\n[objective]\nkind = "min_time"\nsweep = []\n')
    line = _refused(capsys, ["--target", "d50_um=50", "--controller", ctrl, "--hours", "2", *objective],
                    tmp_path / "o")
    assert "objective.sweep" in line and "at least one" in line


def test_a_swept_batch_shorter_than_a_control_interval_is_refused(tmp_path, capsys):
    ctrl = _controller(tmp_path, '\n[objective]\nkind = "min_time"\nsweep = [1e-9]\n')
    line = _refused(capsys, ["--target", "d50_um=50", "--controller", ctrl, "--hours", "2"], tmp_path / "o")
    assert "objective.sweep" in line and "shorter than the 5 min" in line


@pytest.mark.parametrize("hours", ["0.001", "0.02", "0.08"])
def test_hours_shorter_than_the_minimum_milling_period_are_refused(tmp_path, capsys, hours):
    """A batch of a minute or so wrote segments of seconds (`simulate` refused them), under the
    mill's 5 min minimum milling period; a batch shorter than one interval but longer than that
    (0.25 h of a min_time sweep of 1 h) is designed."""
    line = _refused(capsys, ["--target", "d50_um=50", "--hours", hours], tmp_path / "o")
    assert line.startswith("bmctl: error: --hours: ") and "shorter than the 5 min" in line


def test_a_ceiling_at_or_below_the_card_ambient_is_refused(tmp_path, capsys):
    for ceiling in ("20.0", "25.0"):
        ctrl = _controller(tmp_path, **{"ceiling_c": f"ceiling_c = {ceiling}"})
        line = _refused(capsys, ["--target", "d50_um=50", "--controller", ctrl, "--hours", "1"], tmp_path / "o")
        assert "temperature.ceiling_c" in line and "ambient" in line and "25 °C" in line


def test_check_ceiling_passes_a_controller_without_a_ceiling():
    from types import SimpleNamespace as NS

    from bmctl.control.config import check_ceiling, load_controller

    card = NS(thermal=NS(ambient_C=25.0))
    check_ceiling(load_controller(ROOT / "controllers" / "recipe-400rpm-30-10.toml"), card, "r.toml")
    check_ceiling(load_controller(ROOT / "controllers" / "mpc-default.toml"), card, "m.toml")


def test_design_writes_all_of_its_outputs_or_none(tmp_path, capsys, monkeypatch):
    """Ctrl-C while the figure is drawn (the last of the three) leaves no schedule.toml or predicted.csv."""
    import bmctl.control.design as design

    def interrupted(d, path):
        raise KeyboardInterrupt

    monkeypatch.setattr(design, "design_figure", interrupted)
    out = tmp_path / "o"
    rc = main(["design", str(CARD), "--target", "d50_um=42", "--hours", "1", "--plant-seeds", "0",
               "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 130, err
    assert not (out / "schedule.toml").exists() and not (out / "predicted.csv").exists()
    assert not out.exists() or not any(out.iterdir())


def test_target_design_says_when_the_schedule_is_done(tmp_path, capsys):
    """d50 42 µm is reached after minutes of milling: the schedule (its trailing rest not written) is
    done long before the 1 h batch, and both the summary and schedule.toml say so."""
    out = tmp_path / "o"
    assert main(["design", str(CARD), "--target", "d50_um=42", "--hours", "1", "--plant-seeds", "0",
                 "--out", str(out)]) == 0
    text = capsys.readouterr().out
    done = float(text.split("the schedule is done after ")[1].split(" h")[0])
    header = (out / "schedule.toml").read_text(encoding="utf-8").splitlines()[0]
    written = sum(float(ln.split("=")[1].split("#")[0]) for ln in (out / "schedule.toml").read_text(encoding="utf-8").splitlines()
                  if ln.startswith("hours ="))
    assert done == pytest.approx(written, abs=0.005) and done < 1.0
    assert "1 h is the batch length it was designed for" in text
    assert f"the schedule is done after {done:.2f} h" in header


def test_switches_count_the_stop_before_the_batch_end_as_the_budget_does():
    """The search's best cycled schedule (8 bursts over 4 h) ends with a rest, which is not written: the
    schedule has 14 transitions, and the mill switches off once more, at 3.58 h, inside the batch. The
    search kept the budget counting that stop (15), the summary and the family lines said 14. Now every
    count is the budget's: the design, its family line, the search's row, schedule.toml and the figure."""
    from bmctl.control import load_controller
    from bmctl.control.design import batch_switches, design_schedule, schedule_toml, switches_of
    from bmctl.control.mill import count_switches
    from bmctl.moments.model import make_moment_model

    model = make_moment_model(CARD)
    cfg = load_controller(ROOT / "controllers" / "mpc-default.toml")
    d = design_schedule(model, {"s_mean_um": 35.0}, 4.0, cfg, local=False)
    assert d.done_h < d.hours - 0.1 and d.segments[-1][1] > 0  # the last milling stops before the batch end
    fam = d.reach.per_family[d.searched.family]
    assert count_switches(d.segments) == 14
    searched = d.search.per_family[d.searched.family]["switches"]  # the search's own count, its budget's
    assert fam["switches"] == d.switches == switches_of(d.result) == searched == 15
    for name, row in d.reach.per_family.items():  # every family's row as the search's budget counted it
        assert row["switches"] == d.search.per_family[name]["switches"], name
    line = next(ln for ln in d.reach.family_lines() if ln.strip().startswith(d.searched.family))
    assert "15 switches" in line
    head = schedule_toml(d).splitlines()
    assert "that stop counts as an on/off switch" in head[0] and "; 15 on/off switches;" in head[1]
    assert batch_switches(d.segments, d.done_h) == 14  # a batch ending with its last milling: no stop inside it


def test_design_summary_counts_the_early_stop(tmp_path, capsys):
    """d50 42 µm takes one short period of milling in a 1 h batch: one on/off switch, the stop."""
    out = tmp_path / "o"
    assert main(["design", str(CARD), "--target", "d50_um=42", "--hours", "1", "--plant-seeds", "0",
                 "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "1 segment, 1 on/off switch, " in text.splitlines()[0], text
    assert "; 1 on/off switch;" in (out / "schedule.toml").read_text(encoding="utf-8").splitlines()[1]


def test_family_errors_are_those_of_the_written_schedule(tmp_path):
    """With 3-min milling and 2-min rests the search's cheaper prediction put its best (cycled) schedule
    at 7.7 % off s_mean_um=35; the summary, integrating the written schedule, said 8.6 %. The family
    line now gives the written schedule's error and peak, as the summary does."""
    import numpy as np

    from bmctl.control import load_controller
    from bmctl.control.design import design_schedule
    from bmctl.moments.model import make_moment_model

    model = make_moment_model(CARD)
    cfg = load_controller(_controller(tmp_path, **{"min_mill_min": "min_mill_min = 3", "min_rest_min": "min_rest_min = 2",
                                                   "max_switches": "max_switches = 60"}))
    d = design_schedule(model, {"s_mean_um": 35.0}, 4.0, cfg, local=False)
    fam = d.reach.per_family[d.searched.family]
    assert np.isclose(fam["error"], d.result.error, rtol=1e-9)
    assert np.isclose(fam["peak_c"], d.result.peak_c, rtol=1e-9)
    line = next(ln for ln in d.reach.family_lines() if ln.strip().startswith(d.searched.family))
    assert f"error {100 * d.result.error:6.1f} %" in line


def test_design_figure_draws_a_d90_target(tmp_path, monkeypatch):
    """design.png drew s_mean, s_std and d50 with their targets; a d90_um target had no curve and no line."""
    import bmctl.io
    from bmctl.control import load_controller
    from bmctl.control.design import design_figure, design_schedule
    from bmctl.moments.model import make_moment_model

    figs = []
    monkeypatch.setattr(bmctl.io, "savefig", lambda fig, path, **kw: figs.append(fig))
    model = make_moment_model(CARD)
    cfg = load_controller(ROOT / "controllers" / "mpc-default.toml")
    d = design_schedule(model, {"d90_um": 80.0}, 1.0, cfg, local=False)
    design_figure(d, tmp_path / "design.png")
    sizes = figs[0].axes[1]
    labels = [ln.get_label() for ln in sizes.get_lines()]
    assert "D90 (µm, by volume)" in labels and "target D90 (µm, by volume)" in labels
    assert "µm" in sizes.get_ylabel()


def test_predicted_csv_gives_a_window_target_as_its_bounds():
    """A window target was written as its middle (60 for 55:65), a value the design never aimed at."""
    import numpy as np

    from bmctl.control.design import predicted_csv

    class D:
        target = {"d50_um": (55.0, 65.0), "r_mean": 0.05}
        times_h = np.array([0.0, 1.0])
        X = np.zeros((2, 6))
        U = np.array([[300.0, 1.0]])
        t_peak_c = np.array([40.0])

    head, first = predicted_csv(D).splitlines()[:2]
    assert head.endswith("target_d50_um_lo,target_d50_um_hi,target_r_mean")
    assert first.split(",")[-3:] == ["55", "65", "0.05"]


@pytest.mark.slow
def test_the_search_answers_with_its_best_schedule_as_written():
    """Over 48 h the search's cheaper integration drifts: it ranked a two-phase row at 0.04 % off
    s_mean_um=35 that is 3.3 % off as written, over a cycled row at 1.1 %, and the design said "out of
    reach". Each family's best row is now integrated as written and the best of those answers."""
    from bmctl.control import load_controller
    from bmctl.control.design import design_schedule
    from bmctl.moments.model import make_moment_model

    model = make_moment_model(CARD)
    cfg = load_controller(ROOT / "controllers" / "mpc-default.toml")
    d = design_schedule(model, {"s_mean_um": 35.0}, 48.0, cfg, local=False)
    tol = cfg.objective.tolerance
    assert d.reach.reachable and d.result.error <= tol
    errors = {f: row["error"] for f, row in d.reach.per_family.items()}
    assert errors[d.searched.family] <= min(errors.values()) + cfg.plan.error_band
    assert min(errors.values()) <= tol < max(errors.values())  # the families disagree: the choice matters


def test_a_controller_with_no_speed_left_on_the_card_is_refused_before_any_progress(tmp_path, capsys):
    """A controller whose lowest milling speed (650 rpm) lies above the card's mill.rpm_max (600 rpm)
    was refused inside the search, after "design: searching ..." had gone to stderr: two lines."""
    ctrl = _controller(tmp_path, **{"rpm_min = ": "rpm_min = 650.0", "rpm_max = ": "rpm_max = 700.0"})
    line = _refused(capsys, ["--target", "s_mean_um=45", "--hours", "4", "--controller", ctrl], tmp_path / "o")
    assert "no speed is left to mill at" in line and "650 rpm" in line


def test_design_schedule_checks_its_inputs_before_its_first_progress_line(tmp_path):
    from bmctl.control import load_controller
    from bmctl.control.design import design_schedule
    from bmctl.errors import InputError
    from bmctl.moments.model import make_moment_model

    cfg = load_controller(_controller(tmp_path, **{"rpm_min = ": "rpm_min = 650.0", "rpm_max = ": "rpm_max = 700.0"}))
    said = []
    with pytest.raises(InputError, match="no speed is left to mill at"):
        design_schedule(make_moment_model(CARD), {"s_mean_um": 45.0}, 4.0, cfg, progress=said.append)
    assert said == []


def _segment_minutes(text: str) -> list[tuple[float, str]]:
    """(hours, the comment's minutes) of every ``hours = X   # Y min`` line of a schedule.toml."""
    out = []
    for ln in text.splitlines():
        if ln.startswith("hours = "):
            value, comment = ln[len("hours = "):].split("#")
            out.append((float(value), comment.strip().removesuffix(" min")))
    return out


@pytest.mark.parametrize("hours", ["0.09", "0.08334", "0.5"])
def test_schedule_toml_says_the_minutes_it_writes(tmp_path, capsys, hours):
    """A batch of 0.09 h (5.4 min) is one control interval, milled whole: its segment was commented
    `# 5 min` under a header calling every milling time whole minutes. Each comment now gives the
    written length, and the header says whole minutes only where every segment is; a batch of whole
    minutes (0.5 h) is written as before."""
    out = tmp_path / "o"
    rc = main(["design", str(CARD), "--target", "d50_um=45", "--hours", hours, "--plant-seeds", "0",
               "--out", str(out)])
    assert rc == 0, capsys.readouterr().err
    text = (out / "schedule.toml").read_text(encoding="utf-8")
    segs = _segment_minutes(text)
    assert segs
    for h, shown in segs:
        assert float(shown.lstrip("≈ ")) == pytest.approx(h * 60, abs=1e-4), (h, shown)
    whole = all(abs(h * 60 - round(h * 60)) < 1e-6 for h, _ in segs)
    assert ("# rpm 0 = rest; milling times are whole minutes\n" in text) == whole, text
    assert whole == (hours == "0.5")
    if whole:
        assert all(shown == f"{h * 60:.0f}" for h, shown in segs)


@pytest.mark.parametrize("flag", [["--seed", "7"], ["--workers", "2"], ["--plant-particles", "800"]])
def test_plant_check_flags_without_a_plant_check_are_refused(tmp_path, capsys, flag):
    """--plant-seeds 0 skips the plant check: its seed, workers and particles would do nothing."""
    out = tmp_path / "o"
    rc = main(["design", str(CARD), "--target", "d50_um=45", "--hours", "4", "--plant-seeds", "0", *flag,
               "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and f"{flag[0]}: sets the plant check, which --plant-seeds 0 skips" in err
    assert not out.exists()


def test_a_batch_a_hair_under_five_minutes_says_how_far_under():
    """0.0833 h is 4.998 min: the refusal said "(5 min) is shorter than the 5 min"."""
    from bmctl.control.config import validate_controller
    from bmctl.control.design import check_batch
    from bmctl.errors import InputError

    cfg = validate_controller({"kind": "mpc", "interval_h": 0.5}, "c.toml")
    with pytest.raises(InputError, match=r"0\.0833 h \(4\.998 min\) is shorter than the 5 min"):
        check_batch(0.0833, cfg, hours_source="--hours", cfg_source="c.toml")


def test_plant_check_gives_d_values_of_the_particles_and_of_the_size_law():
    """design steers a d50_um target through the size law of (s_mean, s_std) and judged it on the plants'
    particles alone: a 5 % "disagreement" could not be told apart from the law's misfit to the powder."""
    from bmctl.config import load_card
    from bmctl.control.design import _plant_member, plant_check
    from bmctl.parallel import seed_sequences
    from scipy.special import gamma

    card = load_card(CARD)
    segs = [(0.5, 300.0)]
    pc = plant_check(card, segs, {"d50_um": 45.0, "s_mean_um": 40.0}, seeds=2, particles=600, seed=3)
    again = [_plant_member((card, tuple(segs), 600), np.random.default_rng(ss))[0] for ss in seed_sequences(3, 2)]
    law = []
    for m in again:  # the Weibull of each plant's number mean and std, k = cv^-1.086 (docs/fidelity.md)
        cv = m["s_std_um"] / m["s_mean_um"]
        k = max(cv ** -1.086, 1.0)
        a = 1 + 3 / k  # the volume-weighted law of u = (s / lambda)^k is Gamma(a); its median by Wilson-Hilferty
        lam = m["s_mean_um"] / gamma(1 + 1 / k)
        law.append(lam * (a * (1 - 1 / (9 * a)) ** 3) ** (1 / k))
    assert pc["d50_um"]["law_mean"] == pytest.approx(np.mean(law), rel=1e-6)  # Gamma by A&S 6.1.35 in the code
    assert pc["d50_um"]["mean"] == pytest.approx(np.mean([m["d50_um"] for m in again]), rel=1e-12)
    assert "law_mean" not in pc["s_mean_um"]
