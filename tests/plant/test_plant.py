"""The plant: invariants, conservation, reproducibility, snapshot/restore, kinematics."""

import numpy as np
import pytest

from bmctl.config import load_card
from bmctl.errors import InputError
from bmctl.plant import kinematics, make_plant
from bmctl.plant.kinematics import ball_velocity

from ..conftest import CARDS, card_path


@pytest.fixture(scope="module")
def lab():
    return load_card(card_path("alni-1to1-300rpm-lab"))


def test_kinematics_scales_with_rpm_and_rest_has_no_collisions(lab):
    k0 = kinematics(lab, 0.0)
    assert k0.frequency == 0 and k0.mean_power_W == 0
    k3, k4 = kinematics(lab, 300.0), kinematics(lab, 400.0)
    assert k4.v_rms / k3.v_rms == pytest.approx(4 / 3)  # Burgio: v proportional to rpm
    assert k4.mean_power_W / k3.mean_power_W == pytest.approx((4 / 3) ** 3)  # f ~ v, energy ~ v^2
    assert k3.energy_scale * 1.5 == pytest.approx(0.5 * lab.material.impactor_mass_kg * k3.v_rms**2)
    assert ball_velocity(300.0, lab.mill) == pytest.approx(k3.v_rms)


@pytest.mark.parametrize("name", CARDS)
def test_invariants_and_exact_represented_area(name):
    plant = make_plant(card_path(name), seed=11, particles=3000)
    X0 = plant.total_area
    N0 = plant.represented_particles
    for rpm, h in [(plant.card.process.rpm, 3.0), (0.0, 0.5), (500.0, 2.0)]:
        plant.advance(rpm, h)
        assert np.all(plant.s > 0)
        assert np.all((plant.r >= 0) & (plant.r < 1))
        # represented total area sum(w s^2) stays exact (eqn 2)
        assert plant.weight * np.dot(plant.s, plant.s) == pytest.approx(X0, rel=1e-12)
    assert plant.M == 3000
    c = plant.counts
    assert c.bonds > 0 and c.fractures > 0
    # represented number follows the event balance: N grows by fractures, falls by bonds (per sample particle)
    expect = N0 * np.exp((c.fractures - c.bonds) / plant.M)
    assert plant.represented_particles == pytest.approx(expect, rel=0.15)


def test_rest_cools_and_does_not_change_population(lab):
    plant = make_plant(lab, seed=1, particles=1000)
    plant.advance(300.0, 1.0)
    T_hot = plant.temperature_C
    s, r = plant.s.copy(), plant.r.copy()
    plant.advance(0.0, 1.0)
    assert plant.temperature_C < T_hot
    assert plant.temperature_C - lab.thermal.ambient_C < 0.1 * (T_hot - lab.thermal.ambient_C)
    np.testing.assert_array_equal(plant.s, s)
    np.testing.assert_array_equal(plant.r, r)


def test_milling_fraction_splits_interval(lab):
    a = make_plant(lab, seed=5, particles=1000)
    a.advance(300.0, 1.0, milling=0.5)
    b = make_plant(lab, seed=5, particles=1000)
    b.advance(300.0, 0.5)
    b.advance(0.0, 0.5)
    np.testing.assert_array_equal(a.s, b.s)
    assert a.temperature_C == pytest.approx(b.temperature_C)


def test_same_seed_same_result_and_snapshot_restore(lab):
    a = make_plant(lab, seed=3, particles=2000)
    b = make_plant(lab, seed=3, particles=2000)
    a.advance(300.0, 1.0)
    b.advance(300.0, 1.0)
    assert a.moments() == b.moments()
    snap = a.snapshot()
    a.advance(350.0, 1.0)
    first = a.moments()
    a.restore(snap)
    a.advance(350.0, 1.0)
    assert a.moments() == first
    c = make_plant(lab, seed=4, particles=2000)
    c.advance(300.0, 1.0)
    assert c.moments() != b.moments()


def test_sample_is_drawn_from_population(lab):
    plant = make_plant(lab, seed=2, particles=2000)
    plant.advance(300.0, 2.0)
    s_um, r = plant.sample(300, rng=np.random.default_rng(0))
    assert s_um.shape == (300,) and r.shape == (300,)
    assert set(np.round(s_um, 9)).issubset(set(np.round(plant.s * 1e6, 9)))
    with pytest.raises(InputError):
        plant.sample(0)


@pytest.mark.parametrize("kwargs,field", [({"rpm": -1, "hours": 1}, "rpm"), ({"rpm": 300, "hours": -1}, "hours"),
                                          ({"rpm": float("nan"), "hours": 1}, "rpm"),
                                          ({"rpm": 300, "hours": 1, "milling": 1.5}, "milling"),
                                          ({"rpm": 5000, "hours": 1}, "rpm")])
def test_advance_rejects_bad_input(lab, kwargs, field):
    plant = make_plant(lab, seed=0, particles=200)
    with pytest.raises(InputError, match=field):
        plant.advance(**kwargs)


def test_runaway_bonding_is_one_line_not_a_zero_division(tmp_path):
    """A valid card whose bonding outruns fracture (2000 balls of 1 mm) grew particles to 1e104 µm and died in a
    ZeroDivisionError traceback inside the plant (`bmctl simulate`, `bmctl identify`): one line naming the card."""
    text = card_path("alni-1to1-300rpm-lab").read_text(encoding="utf-8").replace("impactor_mass_kg = 4.14e-3\n", "")
    text = text.replace("ball_diameter_m = 0.010", "ball_diameter_m = 0.001").replace("ball_count = 10",
                                                                                      "ball_count = 2000")
    p = tmp_path / "tiny-balls.toml"
    p.write_text(text, encoding="utf-8")
    plant = make_plant(load_card(p), particles=300, seed=1)
    with pytest.raises(InputError, match=r"alni-1to1-300rpm-lab: the plant's particles grew larger than the vial "
                                         r"at 600 rpm") as e:
        for _ in range(24):
            plant.advance(600.0, 0.5)
    assert "\n" not in str(e.value)
