"""Inputs a user can get wrong, each refused in one line before any work (or said as a warning): an
output path that is empty or names a folder where a file is meant, an image that is not one, hidden
files in a samples folder, a pixel size only tables would receive, a coefficient file whose card
fingerprint was edited, a trial sampling at a pixel size that resolves no particle."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from bmctl.cli import main

ROOT = Path(__file__).resolve().parents[1]
LAB = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
SAMPLES = ROOT / "examples" / "samples"
TABLE = SAMPLES / "lab-300rpm-2h.csv"
TIMES = "0.5,1,2,4,8"


def _refused(capsys, argv) -> str:
    rc = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and err.startswith("bmctl: error: "), (rc, err)
    return err.strip()[len("bmctl: error: "):]


@pytest.mark.parametrize("argv,flag", [
    (["measure", TABLE, "--out", "{d}/newdir/"], "--out"),
    (["estimate", LAB, "--samples", SAMPLES, "--times", TIMES, "--out", "{d}/e.csv/"], "--out"),
    (["estimate", LAB, "--samples", SAMPLES, "--times", TIMES, "--write-card", "{d}/c.toml/"], "--write-card"),
])
def test_a_file_output_ending_in_a_slash_is_refused(tmp_path, capsys, argv, flag):
    """Path("newdir/") drops the slash: measure wrote a table *file* named newdir and its measure.json
    into the current folder."""
    argv = [a.format(d=tmp_path) if isinstance(a, str) else a for a in argv]
    line = _refused(capsys, argv)
    assert line.startswith(f"{flag}: ") and "ends in '/', naming a folder; expected a file" in line, line
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv,said", [
    (["simulate", LAB, "--out", ""], "--out: empty path"),
    (["design", LAB, "--target", "s_mean_um=45", "--out", ""], "--out: empty path"),
    (["campaign", "init", "", "--model", LAB, "--target", "d50_um=45"], "DIR: empty path"),
    (["simulate", ""], "'': empty path, expected a file"),
])
def test_an_empty_path_is_refused_not_read_as_the_current_folder(tmp_path, capsys, monkeypatch, argv, said):
    monkeypatch.chdir(tmp_path)
    assert _refused(capsys, argv) == said
    assert list(tmp_path.iterdir()) == []


def test_an_image_that_is_not_one_is_named_as_measure_names_it(tmp_path, capsys):
    """estimate and campaign sample said "z.png: cannot read image (OSError)"."""
    empty = tmp_path / "z.png"
    empty.write_bytes(b"")
    line = _refused(capsys, ["estimate", LAB, "--samples", empty, "--times", "1", "--um-per-px", "1",
                             "--out", tmp_path / "o" / "e.csv"])
    assert line == f"{empty}: cannot read image (not an image file Pillow can read)", line
    png = tmp_path / "cut.png"
    import numpy as np
    from PIL import Image

    Image.fromarray(np.zeros((64, 64), np.uint8)).save(png)
    png.write_bytes(png.read_bytes()[:60])
    line = _refused(capsys, ["estimate", LAB, "--samples", png, "--times", "1", "--um-per-px", "1",
                             "--out", tmp_path / "o" / "e.csv"])
    assert line.startswith(f"{png}: cannot read image (a damaged or truncated PNG: "), line
    assert not (tmp_path / "o").exists()


def test_hidden_files_in_a_samples_folder_are_not_samples(tmp_path, capsys):
    """A ._x.csv (macOS on other file systems) made "--times: 5 time(s) for 6 sample(s)"."""
    folder = tmp_path / "samples"
    shutil.copytree(SAMPLES, folder)
    (folder / "._lab-300rpm-2h.csv").write_bytes(b"\x00\x05\x16\x07")
    rc = main(["estimate", str(LAB), "--samples", str(folder), "--times", TIMES, "--particles", "100",
               "--no-progress", "--out", str(tmp_path / "e.csv")])
    assert rc == 0, capsys.readouterr().err


def test_estimate_past_the_cards_batch_says_it_holds_its_process(tmp_path, capsys):
    rc = main(["estimate", str(LAB), "--samples", str(SAMPLES), "--times", "0.5,1,2,4,13", "--particles", "100",
               "--no-progress", "--out", str(tmp_path / "e.csv")])
    err = capsys.readouterr().err
    assert rc == 0
    assert ("bmctl: warning: --times: the last sample (13 h) is past the card's 12 h batch; its process (300 rpm) "
            "is taken to go on to 13 h: give --schedule for what the mill ran") in err.splitlines(), err


@pytest.mark.parametrize("flag", ["--um-per-px", "--scale-bar-um"])
def test_measure_refuses_a_pixel_size_only_tables_would_get(tmp_path, capsys, flag):
    line = _refused(capsys, ["measure", TABLE, flag, "2", "--out", tmp_path / "t.csv"])
    assert line == f"{flag}: every input is a particle table (.csv, sizes in µm already); it applies to micrographs only"


def test_campaign_sample_passes_the_scale_bar_to_the_measurement(tmp_path, monkeypatch):
    """campaign sample's own refusal told the user to give --scale-bar-um, which it did not take."""
    from bmctl import campaign as cp
    from bmctl.measure import micrograph

    seen = {}
    real = micrograph.measure_micrograph

    def spy(item, **kw):
        seen.update(kw)
        return real(item, **{**kw, "scale_bar_um": None})  # the example's scale is in its metadata

    d = tmp_path / "c"
    cp.init(d, LAB, ROOT / "controllers" / "recipe-300rpm-continuous.toml", {"d50_um": 45.0}, hours=2.0,
            particles=60)
    monkeypatch.setattr(micrograph, "measure_micrograph", spy)
    cp.sample(d, 0.0, [ROOT / "examples" / "micrograph-2h.tif"], scale_bar_um=12.5)
    assert seen == {"um_per_px": None, "scale_bar_um": 12.5}


def test_campaign_init_names_an_inputs_file_in_the_way(tmp_path, capsys):
    d = tmp_path / "c"
    d.mkdir()
    (d / "inputs").write_text("mine\n", encoding="utf-8")
    line = _refused(capsys, ["campaign", "init", d, "--model", LAB, "--target", "d50_um=45"])
    assert line == f"{d / 'inputs'}: is a file, not a folder (the campaign keeps copies of its inputs there)"
    assert sorted(p.name for p in d.iterdir()) == ["inputs"]


def test_linearize_of_a_card_without_a_process_speed_names_the_card(tmp_path, capsys):
    card = tmp_path / "c.toml"
    text = LAB.read_text(encoding="utf-8")
    assert "\nrpm = 300" in text
    card.write_text(text.replace("\nrpm = 300", "\nrpm = 0", 1), encoding="utf-8")
    line = _refused(capsys, ["linearize", card, "--out", tmp_path / "o"])
    assert line == f"{card}: process.rpm (give --rpm): must be in (0, 600] (got 0)", line


@pytest.mark.parametrize("edit,said", [
    (lambda fp: fp[:-1] + ("0" if fp[-1] != "0" else "1"), "is not the fingerprint of its card.values"),
    (lambda fp: 42, "card.fingerprint: expected a string"),
])
def test_an_edited_card_fingerprint_is_refused(tmp_path, edit, said):
    """card show said "its card fingerprint matches this card" of a file whose fingerprint had been edited:
    only card.values were compared."""
    import tomllib

    from bmctl.errors import InputError
    from bmctl.moments.coeffs import read_file

    src = LAB.with_name(LAB.stem + ".moments.toml")
    text = src.read_text(encoding="utf-8")
    fp = tomllib.loads(text)["card"]["fingerprint"]
    new = edit(fp)
    path = tmp_path / src.name
    path.write_text(text.replace(f'fingerprint = "{fp}"', f"fingerprint = {new!r}" if isinstance(new, str)
                                 else f"fingerprint = {new}"), encoding="utf-8")
    assert read_file(src).values  # the shipped file reads
    with pytest.raises(InputError, match=said):
        read_file(path)


@pytest.mark.parametrize("campaign", [False, True])
def test_a_trial_at_a_pixel_size_that_resolves_nothing_is_refused_before_its_folder(tmp_path, capsys, campaign):
    """The first sample failed ("population: only 0 of 40000 particles are resolvable") after the folder
    and its checkpoint were written, naming neither file nor field, and every rerun into it was refused."""
    sc = tmp_path / "s.toml"
    text = (ROOT / "scenarios" / "trial-lab-recipe.toml").read_text(encoding="utf-8")
    text = text.replace('model = "', f'model = "{ROOT}/').replace('config = "', f'config = "{ROOT}/')
    sc.write_text(text.replace("hours = 12", "hours = 1") + "\n[sampling]\num_per_px = 100\n", encoding="utf-8")
    out = tmp_path / "t"
    line = _refused(capsys, ["trial", sc, "--out", out, "--no-progress", *(["--campaign"] if campaign else [])])
    assert line.startswith(f"{sc}: sampling.um_per_px: at 100 µm/px 0 % of the starting powder's particles"), line
    assert not out.exists()


def test_resolvable_share_of_sections_against_the_sphere_law():
    """A planar section at a uniform height through a sphere of diameter s is s sqrt(1 - u^2) across,
    the sphere drawn in proportion to s: for equal spheres the share above d is sqrt(1 - (d/s)^2)."""
    import numpy as np

    from bmctl.measure.sampler import MIN_AREA_PX, resolvable_share

    d_min = np.sqrt(4 * MIN_AREA_PX / np.pi)  # at 1 µm/px
    s = np.full(10, 2 * d_min)
    assert resolvable_share(s, 1.0, section=True) == pytest.approx(np.sqrt(1 - 0.25), rel=1e-12)
    assert resolvable_share(s, 1.0) == 1.0 and resolvable_share(s, 2.01) == 0.0


def _render_scenario(tmp_path, extra: str) -> Path:
    sc = tmp_path / "r.toml"
    sc.write_text(f'model = "{ROOT}/models/alni-1to1-300rpm-lab.toml"\nhours = 1\ntarget = {{ s_mean_um = 45.0 }}\n'
                  '[scenario]\nname = "r"\ndescription = "rendered samples"\n'
                  f'[controller]\nconfig = "{ROOT}/controllers/recipe-300rpm-continuous.toml"\n'
                  f"[sampling]\n{extra}\n", encoding="utf-8")
    return sc


def test_a_rendered_trial_whose_particles_no_field_holds_is_refused(tmp_path, capsys):
    """At 1e-4 µm/px the renderer drew 400,000-px particles for minutes and gigabytes, unrefused."""
    sc = _render_scenario(tmp_path, "render = true\num_per_px = 0.0001")
    line = _refused(capsys, ["trial", sc, "--out", tmp_path / "t", "--no-progress"])
    assert line.startswith(f"{sc}: sampling.um_per_px: at 0.0001 µm/px the starting powder's largest particles are "), line
    assert line.endswith("give a coarser pixel size, or render = false")


def test_the_work_of_a_trial_counts_its_rendered_samples(tmp_path, capsys):
    """The budget ignored render = true: a trial estimated at under 2 CPU s took about 9."""
    from bmctl.commands.trial import _check_trial_work
    from bmctl.errors import InputError
    from bmctl.scenario import load_scenario

    plain = _render_scenario(tmp_path, "render = false")
    (tmp_path / "b").mkdir()
    rendered = _render_scenario(tmp_path / "b", "render = true")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("BMCTL_BUDGET_CPU_H", str(10 / 3600))  # 10 CPU s
        _check_trial_work(load_scenario(plain), plain)
        with pytest.raises(InputError, match="sampling.render/sampling.um_per_px: the run would take"):
            _check_trial_work(load_scenario(rendered), rendered)


def test_a_list_flag_takes_a_value_that_starts_with_a_minus(tmp_path, capsys):
    """`--temperatures -5,,,,` gave "argument --temperatures: expected one argument" (argparse reads a
    value starting with a minus as an option unless it is one plain number); -5 °C is a valid reading."""
    rc = main(["estimate", str(LAB), "--samples", str(SAMPLES), "--times", TIMES, "--temperatures", "-5,,,,",
               "--particles", "100", "--no-progress", "--out", str(tmp_path / "e.csv")])
    assert rc == 0, capsys.readouterr().err
    assert main(["estimate", str(LAB), "--samples", str(SAMPLES), "--times", TIMES, "--particles", "100",
                 "--no-progress", "--out", str(tmp_path / "none.csv")]) == 0
    import csv

    def first_t(name):
        rows = list(csv.DictReader((tmp_path / name).read_text(encoding="utf-8").splitlines()))
        return float(rows[0]["temperature_c"])

    assert first_t("e.csv") < first_t("none.csv") - 5  # the -5 °C reading at 0.5 h was read


@pytest.mark.parametrize("field,value", [("initial_spread", "nan"), ("roughening", "-1.0"), ("adapt_rate", "50.0"),
                                         ("process_noise_per_sqrt_h", "[nan, 0.15, 0.8, 0.8]"),
                                         ("sigma_temperature_c", "inf"), ("param_prior_log_std", "-1.0")])
def test_a_filter_setting_out_of_its_range_is_refused_before_the_trial_writes(tmp_path, capsys, field, value):
    """FilterSettings took NaN, inf and negative values: the trial wrote its folder and then failed on a NaN
    estimate (or ran to the end on nonsense), and every rerun into the folder was refused."""
    sc = _render_scenario(tmp_path, "render = false")
    sc.write_text(sc.read_text(encoding="utf-8") + f"[estimator]\nparticles = 100\n[estimator.pf]\n{field} = {value}\n",
                  encoding="utf-8")
    out = tmp_path / "t"
    line = _refused(capsys, ["trial", sc, "--out", out, "--no-progress"])
    assert line.startswith(f"{sc}: estimator: pf.{field}"), line
    assert not out.exists()


# --- the Python API ---------------------------------------------------------------------------------
@pytest.fixture
def fresh_campaign(tmp_path):
    from bmctl import campaign as cp

    d = tmp_path / "c"
    cp.init(d, LAB, ROOT / "controllers" / "recipe-300rpm-continuous.toml", {"d50_um": 45.0}, hours=2.0,
            particles=60)
    return d


def test_decide_takes_only_a_bool_and_a_missing_note(fresh_campaign):
    """decide(d, "no") was recorded as an acceptance ("no" is truthy); note=None failed in SQLite."""
    from bmctl import campaign as cp

    cp.advise(fresh_campaign)
    for accept in ("no", 1, None):
        with pytest.raises(TypeError, match="decide: accept must be True or False"):
            cp.decide(fresh_campaign, accept)
    with pytest.raises(TypeError, match="decide: note must be a str"):
        cp.decide(fresh_campaign, True, note=3)
    assert cp.decide(fresh_campaign, True, note=None)["accepted"] is True


def test_sample_takes_one_input_and_checks_a_table_given_by_its_columns(fresh_campaign):
    """A path given alone was read character by character ("sample: /: given twice"); a table with a NaN
    failed in SQLite; an empty table's refusal quoted its whole repr."""
    import math

    from bmctl import campaign as cp
    from bmctl.errors import InputError
    from bmctl.measure.tables import ParticleTable

    with pytest.raises(InputError, match=r"^inputs\[0\] \(a table\): particle 1: area_um2 = nan"):
        cp.sample(fresh_campaign, 0.0, [ParticleTable.from_size_aspect([math.nan, 40.0], [0.1, 0.1])])
    with pytest.raises(InputError, match=r"^inputs\[0\] \(a table\): no particles found"):
        cp.sample(fresh_campaign, 0.0, [ParticleTable.empty()])
    assert cp.sample(fresh_campaign, 0.0, str(TABLE))["n"] == 300


@pytest.mark.parametrize("u_prev,said", [([5000.0, 1.0], "u_prev: rpm must be a number in [0, 600]"),
                                         ([300.0, 1.5], "u_prev: milling must be a number in [0, 1]")])
@pytest.mark.parametrize("controller", ["lqr-baseline", "mpc-fast", "mpc-default"])
def test_a_plan_from_an_input_the_mill_cannot_run_is_refused(controller, u_prev, said):
    """A plan from u_prev = 5000 rpm on a 600 rpm mill was made as if the mill had run it."""
    from bmctl.control import make_controller
    from bmctl.errors import InputError
    from bmctl.moments.model import make_moment_model

    model = make_moment_model(LAB)
    ctrl = make_controller(ROOT / "controllers" / f"{controller}.toml", model)
    ctrl.set_target({"s_mean_um": 45.0})
    with pytest.raises(InputError, match=re.escape(said)):
        ctrl.plan(model.x0(), 0.0, u_prev=u_prev)


@pytest.mark.parametrize("edit,said", [
    (lambda st: st.update(queue=[np.array([10 ** 6]), np.array([0]), np.array([1])]), "queue must be three"),
    (lambda st: st.update(queue=[np.array([0, 1]), np.array([1]), np.array([2])]), "queue must be three"),
    (lambda st: st["s"].__setitem__(0, np.nan), "every s must be finite"),
    (lambda st: st["s"].__setitem__(0, -1e-6), "every s must be finite and > 0"),
    (lambda st: st.update(t_s=float("nan")), "t_s >= 0"),
])
def test_a_plant_state_the_events_cannot_run_is_refused_whole(edit, said):
    """Plant.set_state took queue indices out of range (the compiled events then read and wrote past the
    arrays), NaN sizes and a NaN clock."""
    import numpy as np

    from bmctl.plant.plant import Plant

    plant = Plant(LAB, np.random.default_rng(0), 200)
    plant.advance(300.0, 0.05)
    state = plant.get_state()
    state["s"] = np.array(state["s"])
    edit(state)
    before = plant.get_state()
    with pytest.raises(ValueError, match=said):
        plant.set_state(state)
    after = plant.get_state()
    assert np.array_equal(after["s"], before["s"]) and after["t_s"] == before["t_s"]


@pytest.mark.parametrize("kw,exc,said", [
    ({"rpm": "300", "hours": 0.1}, TypeError, "rpm: must be a number"),
    ({"rpm": None, "hours": 0.1}, TypeError, "rpm: must be a number"),
    ({"rpm": [300.0], "hours": 0.1}, TypeError, "rpm: must be a number"),
    ({"rpm": 300.0, "hours": 1e9}, "input", "hours: must be in [0, 1000]"),
])
def test_plant_advance_names_a_bad_argument(kw, exc, said):
    """Types gave numpy's "ufunc 'isfinite' not supported"; 1e9 h was taken (about 12 h of work)."""
    from bmctl.errors import InputError
    from bmctl.plant.plant import Plant

    plant = Plant(LAB, np.random.default_rng(0), 100)
    with pytest.raises(InputError if exc == "input" else exc, match=re.escape(said)):
        plant.advance(**kw)
    with pytest.raises(TypeError, match="card: must be a ModelCard or a card file's path"):
        Plant(5, np.random.default_rng(0), 100)


@pytest.mark.parametrize("kw,exc,said", [
    ({"seeds": 0}, "input", "seeds: must be >= 1"), ({"seeds": 1.5}, TypeError, "seeds: must be a whole number"),
    ({"seeds": True}, TypeError, "seeds: must be a whole number"),
    ({"particles": 2.7}, TypeError, "particles: must be a whole number"),
    ({"particles": "200"}, TypeError, "particles: must be a whole number"),
    ({"base_seed": -1}, "input", "base_seed: must be >= 0"),
])
def test_run_schedule_ensemble_names_a_bad_count(kw, exc, said):
    """seeds=0 gave "need at least one array to concatenate", particles=2.7 ran 2 particles, base_seed=-1
    numpy's SeedSequence error."""
    from bmctl.errors import InputError
    from bmctl.whatif import run_schedule_ensemble

    args = {"seeds": 1, "particles": 100, **kw}
    with pytest.raises(InputError if exc == "input" else exc, match=re.escape(said)):
        run_schedule_ensemble(LAB, "s", [(0.1, 300.0)], **args)
    res = run_schedule_ensemble(str(LAB), "s", [(0.1, 300.0)], seeds=1, particles=100)  # a path is a card
    assert res.traj["s_mean_um"].shape[0] == 1


@pytest.mark.parametrize("kw,exc,said", [
    ({"seed": None}, TypeError, "seed: must be a whole number"), ({"seed": -1}, "input", "seed: must be >= 0"),
    ({"seed": "1"}, TypeError, "seed: must be a whole number"),
    ({"seed": 0, "max_steps": 1.5}, TypeError, "max_steps: must be a whole number"),
    ({"seed": 0, "max_steps": -1}, "input", "max_steps: must be >= 0"),
])
def test_run_trial_names_a_bad_seed_or_step_count(tmp_path, kw, exc, said):
    """seed=None ran a trial nobody could repeat; max_steps=1.5 was ignored and the whole trial ran."""
    from bmctl.errors import InputError
    from bmctl.trial import run_trial

    with pytest.raises(InputError if exc == "input" else exc, match=re.escape(said)):
        run_trial(ROOT / "scenarios" / "trial-lab-recipe.toml", tmp_path / "t", **kw)
    assert not (tmp_path / "t").exists()


@pytest.mark.parametrize("make,said", [
    (lambda S: S.from_pairs([(0.0001, 300.0)]).toml(), "Schedule.toml(): segment[0].hours"),
    (lambda S: S.from_pairs([(0.5, 300.0, 0.0001)]).toml(), "Schedule.toml(): segment[0].milling: mills 0.18 s"),
    (lambda S: S.from_pairs([(1.0, 300.0)], name="a\nb").toml(), "Schedule.toml(): name: text with a control"),
    (lambda S: S.from_pairs([(1.0, 300.0)]).scaled(-2), "factor: must be a finite number > 0"),
    (lambda S: S.from_pairs([(1.0, 300.0)]).scaled(float("nan")), "factor: must be a finite number > 0"),
    (lambda S: S.from_pairs([(1.0, 300.0)]).scaled(1e6), "segment[0].hours: 1e+06 h is outside [0, 1000 h]"),
    (lambda S: S.from_inputs([[300.0, 1.5]], 0.5), "U: rpm must be >= 0 and milling in [0, 1]"),
    (lambda S: S.from_inputs([[-300.0, 1.0]], 0.5), "U: rpm must be >= 0"),
    (lambda S: S.from_inputs([[300.0, 1.0]], -1.0), "interval_h: must be a finite number > 0"),
    (lambda S: S.from_inputs([[300.0, 1.0, 2.0]], 0.5), "U: must be finite (rpm, milling) per interval"),
])
def test_a_schedule_is_refused_where_a_file_could_not_hold_it(make, said):
    """toml() wrote files Schedule.load refused (docs/loop.md: "toml() writes it back so that
    Schedule.load reads the same numbers"); scaled(-2) gave negative hours; from_inputs turned a 1.5
    share into a 0.75 h segment of a 0.5 h interval and -300 rpm into a rest."""
    from bmctl.errors import InputError
    from bmctl.schedule import Schedule

    with pytest.raises(InputError, match=re.escape(said)):
        make(Schedule)
    assert Schedule.from_inputs(np.array([300.0, 0.5, 0.0, 0.0]), 0.5).pairs() == [(0.25, 300.0), (0.75, 0.0)]


def test_a_table_whose_s_um_disagrees_with_its_area_is_refused(tmp_path):
    """area_um2 1256.6 (s = 40 µm) beside s_um = 10 was read as 40 µm without a word."""
    from bmctl.errors import InputError
    from bmctl.measure.tables import read_table

    t = tmp_path / "t.csv"
    t.write_text("area_um2,perimeter_um,s_um,r\n1256.637,125.7,40.0,0.0003\n1256.637,125.7,10,0.5\n", encoding="utf-8")
    with pytest.raises(InputError, match=r"row 3, column s_um: 10 µm disagrees with area_um2's s = 2 sqrt\(A/pi\) = 40"):
        read_table(t)
    t.write_text("area_um2,perimeter_um,s_um,r\n1256.637,125.7,40.0,0.0003\n", encoding="utf-8")
    assert read_table(t).s_um[0] == pytest.approx(40.0, rel=1e-6)
    assert read_table(TABLE).s_um.size == 300  # the tables measure writes agree with themselves


def test_write_table_never_writes_a_row_read_table_refuses(tmp_path):
    """A table with NaN or r = 1 was written as rows (nan,nan,nan,0.1) its own reader then refused."""
    from bmctl.errors import InputError
    from bmctl.measure.tables import ParticleTable, write_table

    for s, r in (([np.nan, 40.0], [0.1, 0.1]), ([10.0], [1.0])):
        with np.errstate(divide="ignore"):  # r = 1: an infinite perimeter
            table = ParticleTable.from_size_aspect(s, r)
        with pytest.raises(InputError, match="write_table: "):
            write_table(tmp_path / "t.csv", table)
        assert not (tmp_path / "t.csv").exists()


@pytest.mark.parametrize("call,said", [
    (lambda st: st.weighted_quantile([1.0, 2.0, 3.0], 1.5), "q must be in [0, 1]"),
    (lambda st: st.weighted_quantile([1.0, np.nan, 3.0], 0.5), "values and weights must be finite"),
    (lambda st: st.weighted_quantile([1.0, 2.0, 3.0], 0.5, [1.0, -1.0, 1.0]), "weights >= 0"),
    (lambda st: st.law_size_stats(-40.0, 4.0), "mean must be finite and > 0"),
    (lambda st: st.lognormal_size_stats(0.0, 4.0), "mean must be finite and > 0"),
])
def test_size_statistics_refuse_what_they_cannot_describe(call, said):
    """weighted_quantile(.., 1.5) gave the largest value, a NaN was skipped, a negative weight taken;
    law_size_stats(-40, 4) gave complex D-values and lognormal_size_stats(0, 4) a ZeroDivisionError."""
    from bmctl import stats

    with pytest.raises(ValueError, match=re.escape(said)):
        call(stats)
    assert float(stats.weighted_quantile([1.0, 2.0, 3.0], 0.5)) == 2.0


@pytest.mark.parametrize("call,exc,said", [
    (lambda m, ctl: m.step(m.x0(), [300.0, 1.0], None), TypeError, "dt_h: must be a number of hours"),
    (lambda m, ctl: m.step(m.x0(), [300.0, 1.0], 0.5, substeps=2.7), TypeError, "substeps: must be a whole number"),
    (lambda m, ctl: m.simulate(m.x0(), np.zeros((0, 2)), -1.0), "input", "dt_h: must be a finite number > 0"),
    (lambda m, ctl: ctl.make_controller(ROOT / "controllers" / "mpc-fast.toml", None), TypeError,
     "model: must be a moment model"),
    (lambda m, ctl: ctl.make_controller(ROOT / "controllers" / "mpc-fast.toml", m).set_target("d50_um=45"),
     TypeError, "target: a dict such as"),
])
def test_model_and_controller_arguments_are_named(call, exc, said):
    """dt_h=None gave float()'s message, substeps=2.7 ran 2, a negative dt_h passed with an empty U,
    a controller on model None failed deep inside, and a target given as text was read as characters."""
    from bmctl import control
    from bmctl.errors import InputError
    from bmctl.moments.model import make_moment_model

    with pytest.raises(InputError if exc == "input" else exc, match=re.escape(said)):
        call(make_moment_model(LAB), control)


def test_particle_filter_takes_its_settings_as_a_dict_and_names_a_missing_model():
    from bmctl.estimate import ParticleFilter
    from bmctl.moments.model import make_moment_model

    pf = ParticleFilter(make_moment_model(LAB), np.random.default_rng(0), {"n_particles": 100})
    assert pf.settings.n_particles == 100
    with pytest.raises(TypeError, match="model: must be a moment model"):
        ParticleFilter(None, np.random.default_rng(0))
    with pytest.raises(TypeError, match="settings: must be a FilterSettings or a dict"):
        ParticleFilter(make_moment_model(LAB), np.random.default_rng(0), 100)


@pytest.mark.parametrize("kw,said", [({"min_area_px": -5}, "min_area_px: expected a number of px >= 1"),
                                     ({"min_area_px": float("nan")}, "min_area_px: expected a number of px >= 1"),
                                     ({"crop": (0, 5)}, "crop: expected (y0, y1, x0, x1)"),
                                     ({"crop": (0.5, 100.5, 0, 300)}, "crop: expected (y0, y1, x0, x1)")])
def test_measure_micrograph_names_a_bad_detection_limit_or_crop(kw, said):
    from bmctl.errors import InputError
    from bmctl.measure.micrograph import measure_micrograph

    with pytest.raises(InputError, match=re.escape(said)):
        measure_micrograph(ROOT / "examples" / "micrograph-2h.tif", **kw)


def test_a_full_disk_is_named_when_a_campaign_cannot_be_opened(fresh_campaign, monkeypatch):
    """On a full disk `campaign status` said only "cannot be read as a bmctl campaign database (disk I/O
    error)", as if the database were damaged."""
    import os
    import sqlite3
    from types import SimpleNamespace

    from bmctl.campaign import db
    from bmctl.errors import InputError

    def no_room(*a, **k):
        raise sqlite3.OperationalError("disk I/O error")

    monkeypatch.setattr(db.sqlite3, "connect", no_room)
    with pytest.raises(InputError, match=r"\(disk I/O error\)$"):  # a disk with room: nothing more is claimed
        db.open_db(fresh_campaign, read_only=True)
    monkeypatch.setattr(os, "statvfs", lambda p: SimpleNamespace(f_bavail=0, f_frsize=4096))
    with pytest.raises(InputError, match=r"\(disk I/O error\); the disk is full"):
        db.open_db(fresh_campaign, read_only=True)


def test_card_show_of_a_card_without_a_process_speed_says_where_its_table_is(tmp_path, capsys):
    """With process.rpm = 0 the table showed 150-375 rpm, as if the card said 300, without a word."""
    card = tmp_path / "c.toml"
    card.write_text(LAB.read_text(encoding="utf-8").replace("\nrpm = 300", "\nrpm = 0", 1), encoding="utf-8")
    assert main(["card", "show", str(card)]) == 0
    err = capsys.readouterr().err
    assert "bmctl: note: the card's process.rpm is 0 (no recipe speed): the table is around half its rpm_max " \
           "(300 rpm)" in err, err
    assert main(["card", "show", str(LAB)]) == 0 and "process.rpm is 0" not in capsys.readouterr().err
