"""Coefficients belong to a card: fingerprint, refusal, --identify, calibrated cards, the operating window."""

import shutil

import numpy as np
import pytest

from bmctl.cards import (FINGERPRINT_SKIP, FINGERPRINT_TABLES, fingerprint, fingerprint_diff, fingerprint_values,
                         steady_temperature_c, window_warnings)
from bmctl.cli import main
from bmctl.config import ModelCard, load_card
from bmctl.errors import InputError
from bmctl.moments import coeffs as cf
from bmctl.moments.forcard import for_card, is_shipped, status

from ..conftest import CARDS, card_path

LAB = card_path("alni-1to1-300rpm-lab")


def _copy(tmp_path, old=None, new=None, name="card.toml", coeffs=True):
    """The lab card (one text replaced) and, with ``coeffs``, the lab's coefficient file next to it."""
    text = LAB.read_text(encoding="utf-8")
    if old is not None:
        assert old in text
        text = text.replace(old, new)
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    if coeffs:
        shutil.copyfile(cf.coeffs_path(LAB), cf.coeffs_path(p))
    return p


@pytest.mark.parametrize("name", CARDS)
def test_every_shipped_card_has_its_own_coefficients(name):
    """Fails when a shipped card is edited (a fingerprinted field) without re-identifying it."""
    st = status(load_card(card_path(name)), card_path(name))
    assert st.state == "match", st.line()
    assert st.file.card_name == name
    assert set(st.file.heldout_mean) >= {"s_mean_um", "s_std_um", "r_mean", "r_std"}
    assert for_card(card_path(name)).coeff_file.card_name == name


def test_a_changed_card_field_is_refused_naming_card_field_and_fix(tmp_path):
    p = _copy(tmp_path, "gamma_per_um2 = 1.82e-4", "gamma_per_um2 = 2.73e-4")
    with pytest.raises(InputError) as e:
        for_card(p)
    msg = str(e.value)
    assert "\n" not in msg
    assert msg.startswith(f"{p}: moment coefficients:")
    assert "stochastic.gamma_per_um2 0.000273 (coefficients: 0.000182)" in msg
    assert f"bmctl identify {p}" in msg and "or add identify=True" in msg


def test_missing_and_unrecorded_coefficients_are_refused(tmp_path):
    p = _copy(tmp_path, coeffs=False)
    with pytest.raises(InputError, match="none identified for this card"):
        for_card(p)
    # a file from before fingerprints: no [card] table, so it may belong to any card
    text = cf.coeffs_path(LAB).read_text(encoding="utf-8")
    cut = text[:text.index("[card]")] + text[text.index("[window]"):]
    cf.coeffs_path(p).write_text(cut, encoding="utf-8")
    with pytest.raises(InputError, match="records no card fingerprint"):
        for_card(p)


def test_a_fingerprinted_file_lacking_coefficients_is_refused(tmp_path, capsys):
    """A coefficient file with the card's fingerprint but coefficients deleted (hand edit, bad merge) would run
    the model on defaults for them (held-out error ~20 % instead of ~4 %): refused in one line naming them."""
    p = _copy(tmp_path)
    text = cf.coeffs_path(p).read_text(encoding="utf-8")
    cf.coeffs_path(p).write_text(text.replace(next(ln for ln in text.splitlines() if ln.startswith("bond_slope"))
                                              + "\n", ""), encoding="utf-8")
    with pytest.raises(InputError, match=r"lacks 1 of the \d+ coefficients \(bond_slope\)") as e:
        for_card(p)
    assert "\n" not in str(e.value) and f"bmctl identify {p}" in str(e.value)
    start, end = text.index("[coefficients]\n") + len("[coefficients]\n"), text.index("[card]")
    cf.coeffs_path(p).write_text(text[:start] + "\n" + text[end:], encoding="utf-8")  # an empty [coefficients]
    assert status(load_card(p), p).state == "incomplete"
    assert main(["card", "show", str(p)]) == 0 and "lacks" in capsys.readouterr().out


def test_matching_copy_is_accepted(tmp_path):
    """A card elsewhere with the same fingerprint fields (other name, recipe, plant settings) is accepted."""
    p = _copy(tmp_path, 'name = "alni-1to1-300rpm-lab"', 'name = "my-copy"')
    text = p.read_text(encoding="utf-8").replace("rpm = 300\n", "rpm = 350\n", 1).replace("particles = 20000", "particles = 5000")
    p.write_text(text, encoding="utf-8")
    assert for_card(p).coeff_file.card_name == "alni-1to1-300rpm-lab"


def test_card_object_needs_a_named_file():
    with pytest.raises(InputError, match="card alni-1to1-300rpm-lab: moment coefficients: none given"):
        for_card(load_card(LAB))
    assert for_card(load_card(LAB), coeffs=cf.coeffs_path(LAB)).coeff_file is not None


# --- which fields the fingerprint covers ----------------------------------------------------------------


def _bumped(card: ModelCard, table: str, field: str) -> ModelCard:
    d = card.model_dump()
    v = d[table][field]
    d[table][field] = (v + 1) if isinstance(v, int) else (v * 1.01 if v else 0.01)
    if (table, field) == ("mill", "speed_ratio"):
        d[table][field] = v * 0.99
    return ModelCard.model_validate(d)


def test_every_fingerprint_field_changes_the_fingerprint():
    card = load_card(LAB)
    base = fingerprint_values(card)
    for key in base:
        table, field = key.split(".")
        other = fingerprint_values(_bumped(card, table, field))
        assert fingerprint_diff(other, base) and fingerprint(other) != fingerprint(base), key


def test_fields_left_out_of_the_fingerprint_do_not_move_the_model():
    """Every card field outside the fingerprint leaves the model's constants and default coefficients as they
    are: the fingerprint covers everything the model reads from the card."""
    from bmctl.moments.model import default_coeffs
    from bmctl.moments.physics import constants

    card = load_card(LAB)
    c0, q0 = constants(card), default_coeffs(card)
    left_out = [("process", "rpm"), ("process", "hours"), ("simulation", "particles"),
                ("simulation", "record_every_h"), ("simulation", "batch_fraction"), ("simulation", "max_step_s"),
                ("simulation", "s_max_um")]
    for table, field in left_out:
        assert f"{table}.{field}" not in fingerprint_values(card)
        d = card.model_dump()
        d[table][field] = d[table][field] * 0.9 if field != "particles" else 1000
        other = ModelCard.model_validate(d)
        assert constants(other) == c0 and default_coeffs(other) == q0, (table, field)
    tables = set(ModelCard.model_fields) - set(FINGERPRINT_TABLES)
    assert tables == {"card", "process", "powder", "validity", "simulation"}
    assert FINGERPRINT_SKIP == {"mill.ball_material"}


# --- commands refuse, and say so in one line ------------------------------------------------------------


@pytest.mark.parametrize("argv", [
    ["design", "{card}", "--target", "s_mean_um=30", "--out", "{out}"],
    ["estimate", "{card}", "--samples", "{sample}", "--times", "1", "--out", "{out}/e.csv"],
    ["linearize", "{card}", "--out", "{out}"],
    ["campaign", "init", "{out}", "--model", "{card}", "--controller", "controllers/mpc-default.toml",
     "--target", "s_mean_um=30"],
])
def test_commands_refuse_foreign_coefficients(tmp_path, capsys, argv, root, monkeypatch):
    monkeypatch.chdir(root)
    p = _copy(tmp_path, "ball_count = 10", "ball_count = 12")
    out = tmp_path / "out"
    sample = tmp_path / "s.csv"
    sample.write_text("s_um,r\n" + "".join(f"{40 + k % 7},{0.01 * (k % 5)}\n" for k in range(60)), encoding="utf-8")
    rc = main([a.format(card=p, out=out, sample=sample) for a in argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert err[0].startswith(f"bmctl: error: {p}: moment coefficients:") and "mill.ball_count 12" in err[0]
    assert not out.exists() or not any(out.iterdir())


def test_trial_refuses_a_scenario_card_without_coefficients(tmp_path, capsys):
    from ..campaign.scenarios import lqr_scenario

    p = _copy(tmp_path, coeffs=False)
    s = lqr_scenario(tmp_path / "sc.toml")
    s.write_text(s.read_text(encoding="utf-8").replace(str(LAB), str(p)), encoding="utf-8")
    rc = main(["trial", str(s), "--out", str(tmp_path / "t"), "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and err[0].startswith(f"bmctl: error: {p}: moment coefficients: none identified")
    assert not (tmp_path / "t" / "trajectory.csv").exists()


# --- calibrated cards come with their coefficients -------------------------------------------------------


def test_calibrated_card_is_written_with_its_coefficients(tmp_path, monkeypatch):
    """run_calibration writes ``<card>-calibrated.toml`` and ``<card>-calibrated.moments.toml`` whose fingerprint
    is the calibrated card's. The plant fit and the identification are replaced by stand-ins (the stand-in
    identification records the card it was given); the slow end-to-end test runs the real ones."""
    from types import SimpleNamespace

    from bmctl.calibrate import outputs
    from bmctl.calibrate import run as cal_run
    from bmctl.moments import forcard
    from bmctl.moments import identify as ident

    seen = []

    def fake_text(card, card_path, **kw):
        seen.append(card)
        return cf.toml_text(cf.load_coeffs(cf.coeffs_path(LAB)), {"card": ident.card_table(card)})

    card = load_card(LAB)
    values = [card.stochastic.gamma_per_um2 * 1.5, card.stochastic.delta_per_um2 * 0.6]
    monkeypatch.setattr(forcard, "identification_text", fake_text)
    monkeypatch.setattr(cal_run, "calibrate", lambda *a, **k: SimpleNamespace(values=values))
    monkeypatch.setattr(cal_run, "model_samples_at", lambda *a, **k: [])
    monkeypatch.setattr(outputs, "sample_distances", lambda *a, **k: [])
    monkeypatch.setattr(outputs, "calibration_dict", lambda *a, **k: {})
    res = cal_run.run_calibration(card, LAB, [], ["gamma", "delta"], tmp_path, moment_stage=False)
    new = tmp_path / "alni-1to1-300rpm-lab-calibrated.toml"
    assert new in res.paths and cf.coeffs_path(new) in res.paths
    assert len(seen) == 1 and seen[0].stochastic.gamma_per_um2 == pytest.approx(values[0])
    assert status(load_card(new), new).state == "match"
    with pytest.raises(InputError, match="stochastic.gamma_per_um2"):  # the lab's own coefficients do not fit it
        for_card(load_card(new), coeffs=cf.coeffs_path(LAB))


# --- shipped files and the operating window ------------------------------------------------------------


def test_identify_will_not_overwrite_a_shipped_file(capsys):
    assert is_shipped(cf.coeffs_path(LAB))
    rc = main(["identify", str(LAB), "--quick"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "shipped" in err[0] and "--overwrite" in err[0]


def _fast_mill(tmp_path):
    """The lab card on a mill whose rpm_max is 1000 rpm: 1527 °C steady vial there, above Al's 660 °C."""
    return _copy(tmp_path, "rpm_max = 600", "rpm_max = 1000", name="fast.toml", coeffs=False)


def test_identify_experiments_keep_the_steady_vial_under_the_melting_limit(tmp_path):
    """At rpm_max 1000 rpm the training, held-out and off-card experiments milled at up to 1000 rpm, a
    steady vial of about 1525 °C, far above the melting point: they now stop at the fastest 10-rpm step
    whose steady vial stays under it, and the [window] says so."""
    from bmctl.cards import melting_limit
    from bmctl.moments import identify as ident

    card = load_card(_fast_mill(tmp_path))
    limit = melting_limit(card)[0]
    assert steady_temperature_c(card, 1000.0) > 1500.0 > limit
    for specs in (ident.design(card, 0), ident.design(card, 0, quick=True), ident.validation_design(card, 0, 24),
                  ident.off_card_design(card)):
        rpms = {rpm for s in specs for rpm, duty in list(s.prefix) + list(s.inputs) if rpm > 0 and duty > 0}
        assert max(steady_temperature_c(card, r) for r in rpms) <= limit, sorted(rpms)[-3:]
    top = max(rpm for s in ident.design(card, 0) for rpm, _ in s.inputs)
    assert steady_temperature_c(card, top + 10.0) > limit  # the fastest step under the limit, not lower
    win = ident.design_window(card, ident.design(card, 0))
    assert win["rpm"][1] == top and win["temperature_c"][1] <= limit
    assert "1000 rpm" in win["speed_limit"] and f"{top:g} rpm at most" in win["speed_limit"]


def test_identify_warns_in_one_line_when_it_stops_below_rpm_max(tmp_path, capsys, monkeypatch):
    """The warning comes before any plant run (here the first one is cut short), also with --quiet."""
    from bmctl.moments import identify as ident

    def stop(*a, **k):
        raise InputError("stopped before the plant runs")

    monkeypatch.setattr(ident, "run_experiments", stop)
    card = _fast_mill(tmp_path)
    rc = main(["identify", str(card), "--quick", "--quiet", "--workers", "0",
               "--out", str(tmp_path / "c.moments.toml")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 2, err
    assert err[0].startswith("bmctl: warning: alni-1to1-300rpm-lab: at rpm_max 1000 rpm the steady vial would "
                             "reach 1527 °C, above 660.3 °C (the melting point of Al)"), err
    assert "750 rpm at most" in err[0] and err[1] == "bmctl: error: stopped before the plant runs"


@pytest.mark.parametrize("name", CARDS)
def test_shipped_cards_identify_over_their_whole_speed_range(name):
    """The melting-limit stop leaves the shipped cards' experiments as they were: their design spans
    the window their coefficient files record (up to rpm_max, 349 °C), so re-identification is unchanged."""
    from bmctl.moments import identify as ident

    card = load_card(card_path(name))
    win = ident.design_window(card, ident.design(card, 0))
    rec = cf.read_file(cf.coeffs_path(card_path(name))).window
    assert win["rpm"] == list(rec["rpm"]) and win["rpm"][1] == card.mill.rpm_max
    assert win["temperature_c"] == list(rec["temperature_c"]) and "speed_limit" not in win
    assert ident.speed_limit(card) == (card.mill.rpm_max, "")


def test_steady_temperature_is_the_first_order_vial_balance():
    """T_ss = T_amb + P tau / C (docs/model.md Sec. 4) with P the mean dissipated power of the kinematics."""
    from bmctl.physics.kinematics import kinematics

    card = load_card(LAB)
    th = card.thermal
    for rpm in (150.0, 300.0, 600.0):
        P = kinematics(card, rpm).mean_power_W
        assert steady_temperature_c(card, rpm) == pytest.approx(25.0 + P * 900.0 / 400.0, rel=1e-12)
    assert steady_temperature_c(card, 0.0) == th.ambient_C


def test_window_warns_outside_the_calibrated_temperatures(tmp_path):
    card = load_card(LAB)
    assert window_warnings(card, [150.0, 300.0, 0.0]) == []
    w = window_warnings(card, [300.0, 600.0])
    assert len(w) == 1 and "600 rpm" in w[0] and "°C" in w[0]
    # the example: bigger balls in a bigger vial are hot at the card's own rpm
    big = _copy(tmp_path, "ball_diameter_m = 0.010", "ball_diameter_m = 0.015", coeffs=False)
    text = big.read_text(encoding="utf-8").replace("impactor_mass_kg = 4.14e-3\n", "").replace("ball_count = 10", "ball_count = 12")
    text = text.replace("vial_radius_m = 0.0225", "vial_radius_m = 0.035").replace("vial_height_m = 0.05",
                                                                                     "vial_height_m = 0.065")
    big.write_text(text, encoding="utf-8")
    bc = load_card(big)
    T = steady_temperature_c(bc, 300.0)
    assert T > 200.0
    w = window_warnings(bc, [300.0])
    assert len(w) == 1 and f"{T:.0f} °C at 300 rpm" in w[0]
    # the coefficient file's window narrows it further
    assert window_warnings(card, [300.0], {"temperature_c": (25.0, 60.0)})
    assert not window_warnings(card, [300.0], {"temperature_c": (25.0, 349.0)})


def test_window_slack_and_the_printed_temperature_lies_outside_the_printed_window():
    """The calibration's own 400 rpm (its steady vial is the card's rounded maximum) does not warn; a
    temperature just past a window's end prints with the decimals that show it outside."""
    import re

    card = load_card(LAB)
    assert window_warnings(card, [400.0]) == []
    T = steady_temperature_c(card, 300.0)
    for hi in (T - 0.51, T - 0.6, T - 0.95, T - 3.0):
        (w,) = window_warnings(card, [300.0], {"temperature_c": (25.0, hi)})
        t_txt, hi_txt = re.search(r"temperature ([0-9.]+) °C at 300 rpm is outside [0-9.]+–([0-9.]+) °C", w).groups()
        assert float(t_txt) > float(hi_txt), w


def test_card_show_says_whether_the_card_has_coefficients(tmp_path, capsys):
    assert main(["card", "show", str(LAB)]) == 0
    out = capsys.readouterr().out
    r_mean = cf.read_file(cf.coeffs_path(LAB)).heldout_mean["r_mean"]
    assert "fingerprint matches" in out and "held-out NRMSE" in out and f"r_mean {100 * r_mean:.1f} %" in out
    p = _copy(tmp_path, "alpha = 2.1", "alpha = 2.2")
    assert main(["card", "show", str(p)]) == 0
    out = capsys.readouterr().out
    assert "other values of 1 field(s): stochastic.alpha 2.2 (coefficients: 2.1)" in out and "refuse" in out


# --- fast identification -----------------------------------------------------------------------------


def _short_experiments(model):
    from bmctl.moments import identify as ident

    out = []
    for name, U, p in (("a", [[300.0, 1.0]] * 4, (1.0, 1.0)), ("b", [[500.0, 1.0], [150.0, 1.0], [0.0, 1.0]], (1.2, 0.9))):
        Y = model.simulate(model.x0(), np.array(U), 0.5, p=np.array(p))
        out.append(ident.Experiment(name, np.array(U), Y, np.zeros_like(Y), p=np.array(p)))
    return out


def test_sensitivities_are_the_derivatives_of_the_model_step():
    """The fit's trajectories equal MomentModel.simulate, and their sensitivities dx/dtheta match central
    differences of those trajectories (relative 1e-5), bit for bit the same for any thread count."""
    from bmctl.moments import identify as ident

    model = for_card(LAB)
    free = ("bond_log_scale", "frac_slope", "r_size_corr", "round_rpm_slope")
    fixed = {k: v for k, v in model.coeffs.items() if k not in free}
    th = np.array([model.coeffs[k] for k in free])
    exps = _short_experiments(model)
    s1 = ident._Sensitivities(model, free, fixed, 0.5, threads=1)
    s2 = ident._Sensitivities(model, free, fixed, 0.5, threads=2)
    r1, r2 = s1.run(exps, th, sensitivities=True), s2.run(exps + exps[:1], th, sensitivities=True)
    for (X, S), (X2, S2), e in zip(r1, r2, exps):
        np.testing.assert_allclose(X, e.Y[1:], rtol=1e-12, atol=0)
        assert np.array_equal(X, X2) and np.array_equal(S, S2)
        for i in range(len(free)):
            d = np.zeros_like(th)
            d[i] = 1e-6 * max(1.0, abs(th[i]))
            fd = (s1.simulate(e, th + d) - s1.simulate(e, th - d)) / (2 * d[i])
            # relative 1e-5, or 1e-6 in state units where a coefficient hardly moves a run (central differences
            # of a smooth step lose ~1e-7 to rounding)
            assert np.max(np.abs(fd - S[:, :, i])) <= 1e-5 * max(np.max(np.abs(fd)), 0.1), free[i]
        assert np.max(np.abs(S[:, 0, 0])) > 1.0  # the bonding scale moves s_mean by microns


def test_warm_start_carries_the_nearest_cards_corrections():
    """From a card's own file the start is that file's coefficients; for a card with another alpha the derived
    threshold laws move with the card while their identified corrections carry over."""
    from bmctl.moments import identify as ident
    from bmctl.moments.model import default_coeffs

    cands = ident.identified_candidates()
    assert {c.card_name for c in cands} >= set(CARDS)
    card = load_card(LAB)
    start, label = ident.warm_start(card, cands)
    lab = cf.read_file(cf.coeffs_path(LAB))
    assert "alni-1to1-300rpm-lab" in label
    assert all(start[k] == pytest.approx(v, abs=1e-12) for k, v in lab.coeffs.items())
    other = card.model_copy(update={"stochastic": card.stochastic.model_copy(update={"alpha": 2.6})})
    start, _ = ident.warm_start(other, [lab])
    d_new, d_lab = default_coeffs(other), default_coeffs(card)
    assert d_new["bond_slope"] != pytest.approx(d_lab["bond_slope"])
    assert start["bond_slope"] == pytest.approx(d_new["bond_slope"] + lab.coeffs["bond_slope"] - d_lab["bond_slope"])
    assert start["r_size_corr"] == lab.coeffs["r_size_corr"]
    assert ident.warm_start(card, [])[1].startswith("the built-in defaults")


def test_identify_never_starts_from_the_file_it_replaces(tmp_path, monkeypatch):
    """A second `bmctl identify` of a card must not warm-start from the first one's output (the card's own
    file, the nearest of all): the same seed then gives the same coefficients. --out: that file is left out."""
    from bmctl.moments import forcard
    from bmctl.moments import identify as ident

    p = _copy(tmp_path, "alpha = 2.1", "alpha = 2.2", coeffs=False)
    card = load_card(p)
    own = cf.toml_text(cf.read_file(cf.coeffs_path(LAB)).coeffs, {"card": ident.card_table(card)})
    cf.coeffs_path(p).write_text(own, encoding="utf-8")  # an earlier identification of this very card
    (tmp_path / "other.moments.toml").write_text(own, encoding="utf-8")
    seen = []
    monkeypatch.setattr(ident, "identify", lambda card, seed, **kw: seen.append(kw["start_label"]))
    forcard.identification(card, p, workers=0, quick=True)
    forcard.identification(card, p, workers=0, quick=True, replaces=tmp_path / "other.moments.toml")
    assert "other.moments.toml" in seen[0] and str(cf.coeffs_path(p)) not in seen[0]
    assert str(cf.coeffs_path(p)) in seen[1] and "other.moments.toml" not in seen[1]

@pytest.mark.slow
def test_identify_reports_every_phase_and_writes_next_to_the_card(tmp_path, capsys):
    """`bmctl identify --quick` on a new card (15 mm balls, derived mass): progress lines for the plant
    experiments, the fit and the validation; the held-out error per output at the end; the file next to the
    card, with the card's fingerprint, accepted by for_card. Two Jacobians per start (--jacobians 2): what is
    checked here is the reporting and the file, not how far the fit gets (tests/moments/test_moments.py)."""
    p = _copy(tmp_path, "ball_diameter_m = 0.010", "ball_diameter_m = 0.015", coeffs=False)
    p.write_text(p.read_text(encoding="utf-8").replace("impactor_mass_kg = 4.14e-3\n", ""), encoding="utf-8")
    assert main(["identify", str(p), "--quick", "--jacobians", "2", "--workers", "0"]) == 0
    cap = capsys.readouterr()
    for phase in ("plant experiments: ", "step 1, cost", "validation: held-out NRMSE"):
        assert phase in cap.err, phase
    assert "nearest identified card" in cap.err
    assert "held-out NRMSE per output" in cap.out
    st = status(load_card(p), p)
    assert st.state == "match" and set(st.file.heldout_mean) >= {"s_mean_um", "r_std"}
    assert for_card(p).coeff_file.card_name == load_card(p).card.name


def test_identify_flag_identifies_on_the_spot_and_writes_next_to_the_card(tmp_path, monkeypatch):
    """for_card(identify=True) on a card without coefficients identifies it (a stand-in here), shows progress and
    writes <card>.moments.toml next to it; the model then runs on them."""
    from types import SimpleNamespace

    from bmctl.moments import forcard
    from bmctl.moments import identify as ident

    p = _copy(tmp_path, "alpha = 2.1", "alpha = 2.2", coeffs=False)
    lines = []

    def fake(card, card_path, **kw):
        kw["log"]("plant experiments: 1/1 runs")
        coeffs = {**cf.load_coeffs(cf.coeffs_path(LAB)), "bond_log_scale": 0.1}
        return SimpleNamespace(toml=cf.toml_text(coeffs, {"card": ident.card_table(card)}))

    monkeypatch.setattr(forcard, "identification", fake)
    model = for_card(p, identify=True, progress=lines.append)
    assert cf.coeffs_path(p).exists() and model.coeffs["bond_log_scale"] == 0.1
    assert any("identifying" in ln for ln in lines) and "plant experiments: 1/1 runs" in lines
    assert status(load_card(p), p).ok
