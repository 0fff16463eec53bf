"""Model cards: the paper's three cards keep their numbers; derivations and contradictions; card show."""

import math

import pytest

from bmctl import cards
from bmctl.cli import main
from bmctl.config import load_card

from tests.conftest import CARDS, card_path

#: the numbers the paper's cards held before cards derived anything (paper Sec. 4.1; densities by
#: the law of mixtures; 10 x 10 mm steel balls, ratio 10)
PAPER = {"impactor_mass_kg": 4.14e-3, "elastic_modulus_Pa": 120e9, "yield_stress_Pa": 78.7e6,
         "bond_threshold_J_per_m": 6.4}
DENSITY = {"alni-1to1-300rpm-lab": 5200.0, "alni-1to1-400rpm-fan": 5200.0, "alni-1to3-300rpm-hadjiafxenti": 6830.0}


@pytest.mark.parametrize("name", CARDS)
def test_paper_cards_keep_their_numbers(name):
    card = load_card(card_path(name))
    for k, v in PAPER.items():
        assert getattr(card.material, k) == v
    assert card.material.powder_density_kg_m3 == DENSITY[name]
    m = card.mill
    assert (m.ball_density_kg_m3, m.ball_modulus_Pa, m.ball_diameter_m, m.ball_count, m.ball_to_powder_ratio) == \
        (7900.0, 200e9, 0.010, 10, 10.0)


def _old_format(text: str) -> str:
    """The card as it was before [powder] and ball_material existed."""
    lines = text.splitlines(keepends=True)
    out, skip = [], False
    for ln in lines:
        if ln.startswith("[powder]"):
            skip = True
            continue
        if skip and ln.startswith("["):
            skip = False
        if skip or ln.startswith("ball_material"):
            continue
        out.append(ln)
    return "".join(out)


@pytest.mark.slow
def test_old_format_card_loads_and_simulates_identically(tmp_path, capsys):
    src = card_path("alni-1to1-400rpm-fan")
    old = tmp_path / "old.toml"
    old.write_text(_old_format(src.read_text(encoding="utf-8")), encoding="utf-8")
    assert "[powder]" not in old.read_text(encoding="utf-8") and "ball_material" not in old.read_text(encoding="utf-8")
    a, b = load_card(src).model_dump(), load_card(old).model_dump()
    a["mill"].pop("ball_material"), b["mill"].pop("ball_material")
    assert {k: v for k, v in a.items() if k not in ("powder",)} == {k: v for k, v in b.items() if k != "powder"}
    for path, out in ((src, "n"), (old, "o")):
        assert main(["simulate", str(path), "--hours", "1", "--particles", "300", "--seed", "3",
                     "--out", str(tmp_path / out), "--no-progress"]) == 0
    capsys.readouterr()
    assert (tmp_path / "n" / "moments.csv").read_text(encoding="utf-8") == (tmp_path / "o" / "moments.csv").read_text(encoding="utf-8")


def _edit(tmp_path, old, new):
    text = card_path("alni-1to1-300rpm-lab").read_text(encoding="utf-8")
    assert old in text
    p = tmp_path / "c.toml"
    p.write_text(text.replace(old, new, 1), encoding="utf-8")
    return p


def test_15mm_ball_with_a_10mm_ball_mass_is_refused(tmp_path, capsys):
    p = _edit(tmp_path, "ball_diameter_m = 0.010", "ball_diameter_m = 0.015")
    assert main(["card", "show", str(p)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "material.impactor_mass_kg" in err and "15 mm" in err


def test_ball_mass_is_derived_when_left_out(tmp_path):
    p = _edit(tmp_path, "ball_diameter_m = 0.010", "ball_diameter_m = 0.015")
    p.write_text(p.read_text(encoding="utf-8").replace("impactor_mass_kg = 4.14e-3\n", ""), encoding="utf-8")
    card = load_card(p)
    assert card.material.impactor_mass_kg == pytest.approx(7900 * math.pi / 6 * 0.015**3, rel=1e-12)


@pytest.mark.parametrize("old, new, field", [
    ("ball_density_kg_m3 = 7900", "ball_density_kg_m3 = 14900", "mill.ball_density_kg_m3"),  # WC density, steel named
    ("elastic_modulus_Pa = 120e9", "elastic_modulus_Pa = 300e9", "material.elastic_modulus_Pa"),  # above Ni's 207
    ("powder_density_kg_m3 = 5200", "powder_density_kg_m3 = 7000", "material.powder_density_kg_m3"),
    ('materials = ["Al", "Ni"]', 'materials = ["Al", "Unobtainium"]', "powder.materials"),
    ('materials = ["Al", "Ni"]', 'materials = ["Al", "WC"]', "powder.materials"),
])
def test_contradictions_are_refused(tmp_path, capsys, old, new, field):
    p = _edit(tmp_path, old, new)
    assert main(["card", "show", str(p)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and field in err, err


def test_report_matches_kinematics_laws():
    """Burgio velocity and f = Z v / l, computed by hand for the lab mill."""
    card = load_card(card_path("alni-1to1-300rpm-lab"))
    rep = cards.card_report(card, [300.0])
    row = rep["rows"][0]
    wp = 2 * math.pi * 300 / 60
    v = math.sqrt((wp * 0.07) ** 2 + (2 * wp * (0.0225 - 0.005)) ** 2 * (1 + 4))
    assert row["v_ms"] == pytest.approx(v, rel=1e-12)
    assert row["collisions_per_s"] == pytest.approx(10 * v / (0.045 - 0.010), rel=1e-12)
    assert row["impact_energy_mJ"] == pytest.approx(0.5 * 4.14e-3 * v**2 * 1e3, rel=1e-12)
    th = card.thermal
    assert row["steady_temperature_C"] == pytest.approx(th.ambient_C + row["power_W"] * 900 / 400, rel=1e-12)
    assert rep["loading"]["powder_g"] == pytest.approx(4.14, rel=1e-12)
    assert rep["validity"]["temperature_max_C"] == 660.3


def test_card_show_flags_rows_outside_validity(tmp_path, capsys):
    p = _edit(tmp_path, "rpm_max = 600", "rpm_max = 1200")
    assert main(["card", "show", str(p), "--rpm", "300,1200"]) == 0
    out = capsys.readouterr().out
    row = [ln for ln in out.splitlines() if ln.strip().startswith("1200 ")][0]
    assert row.rstrip().endswith("outside")


@pytest.mark.parametrize("old, new, field", [
    ("ball_diameter_m = 0.010", "ball_diameter_m = 10", "mill.ball_diameter_m"),  # mm in a metre field
    ("ball_diameter_m = 0.010", 'ball_diameter_m = "0.010"', "mill.ball_diameter_m"),
    ("ball_count = 10", 'ball_count = "10"', "mill.ball_count"),
    ("ball_count = 10", "ball_count = 10.5", "mill.ball_count"),
    ("ball_count = 10", "ball_count = 0", "mill.ball_count"),
])
def test_a_bad_input_of_a_derivation_is_named_itself(tmp_path, capsys, old, new, field):
    """Not as the ball mass or ball-to-powder ratio derived from it, nor as a 'missing' ratio."""
    p = _edit(tmp_path, old, new)
    p.write_text(p.read_text(encoding="utf-8").replace("impactor_mass_kg = 4.14e-3\n", "")
                 .replace("ball_to_powder_ratio = 10.0\n", "").replace("[powder]", "[powder]\nmass_kg = 0.00414"), encoding="utf-8")
    assert main(["card", "show", str(p)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and f": {field}: " in err and "required field is missing" not in err, err


def test_a_missing_ball_material_names_the_ball_density_not_the_ratio(tmp_path, capsys):
    p = _edit(tmp_path, 'ball_material = "steel"', "")
    p.write_text(p.read_text(encoding="utf-8").replace("ball_density_kg_m3 = 7900\n", "").replace("impactor_mass_kg = 4.14e-3\n", "")
                 .replace("ball_to_powder_ratio = 10.0\n", "").replace("[powder]", "[powder]\nmass_kg = 0.00414"), encoding="utf-8")
    assert main(["card", "show", str(p)]) == 2
    err = capsys.readouterr().err.strip()
    assert ": mill.ball_density_kg_m3: required field is missing" in err and "mill.ball_material" in err, err


@pytest.mark.parametrize("extra", ["s_min_um = 500.0\ns_max_um = 100.0", "s_min_um = 2000.0"])
def test_an_empty_size_validity_range_is_refused(tmp_path, capsys, extra):
    p = _edit(tmp_path, "[validity]", "[validity]\n" + extra)
    assert main(["card", "show", str(p)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "validity.s_m" in err and "empty range" in err, err


@pytest.mark.parametrize("extra, field", [("calibrated_temperature_max_C = 20.0", "calibrated_temperature_max_C"),
                                          ("temperature_max_C = 25.0", "temperature_max_C")])
def test_a_validity_temperature_not_above_the_ambient_is_refused(tmp_path, capsys, extra, field):
    """The card's ambient is 25 °C: a calibrated maximum of 20 °C (an empty window from the ambient up,
    every milling run warned) or a validity maximum at the ambient is refused, naming the field."""
    p = _edit(tmp_path, "[validity]", "[validity]\n" + extra)
    p.write_text("\n".join(ln for ln in p.read_text(encoding="utf-8").splitlines()
                           if not (ln.startswith(field + " ") and "=" in ln and extra not in ln)) + "\n", encoding="utf-8")
    assert main(["card", "show", str(p)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and f"validity.{field}: " in err and "thermal.ambient_C" in err, err


def test_a_run_above_the_cards_validity_rpm_max_warns():
    """``[validity] rpm_max`` below the mill's top speed: a run there warned of nothing (the card's
    statement was used only by ``card show``); a speed within it still says nothing."""
    from bmctl.cards import window_warnings

    card = load_card(card_path("alni-1to1-300rpm-lab"))
    card = card.model_copy(update={"validity": card.validity.model_copy(update={"rpm_max": 300.0})})
    lines = window_warnings(card, [0.0, 250.0, 350.0])
    assert lines and lines[0] == ("alni-1to1-300rpm-lab: 350 rpm is above the card's validity.rpm_max (300 rpm), "
                                  "where it holds: its predictions at that speed are extrapolations")
    assert window_warnings(card, [250.0, 300.0]) == []


def test_card_show_marks_uncalibrated_exactly_where_a_run_warns(capsys):
    """The fan card's own 400 rpm (steady 121.103 °C against a stated 121.1 °C) was marked `uncalib.` by
    `card show` while `simulate` at 400 rpm gives no warning (window_warnings allows WINDOW_SLACK_K)."""
    card = load_card(card_path("alni-1to1-400rpm-fan"))
    rpms = [300.0, 399.0, 400.0, 401.0, 402.0, 405.0, 420.0]
    rows = cards.card_report(card, rpms)["rows"]
    for row in rows:
        warns = any("steady vial temperature" in ln for ln in cards.window_warnings(card, [row["rpm"]]))
        assert row["in_window"] == (not warns), row
    assert rows[2]["in_window"] and not rows[-1]["in_window"]
    assert main(["card", "show", str(card_path("alni-1to1-400rpm-fan")), "--rpm", "400"]) == 0
    row = [ln for ln in capsys.readouterr().out.splitlines() if ln.strip().startswith("400 ")][0]
    assert "uncalib." not in row, row
