"""The Python API refuses what its docstrings rule out, naming the argument, instead of returning
fewer values, NaN states, foreign coefficients or a raw error from deep inside: Plant.sample,
Plant.run_schedule, make_moment_model, MomentModel.simulate / step, the filters' predict, the
ClosedLoop's plan check and run_filter."""

import math
import re
import shutil

import numpy as np
import pytest

from bmctl.errors import InputError
from tests.conftest import ROOT
from tests.loopfakes import FakeController, FakeEstimator, FakeSensor

LAB = ROOT / "models" / "alni-1to1-300rpm-lab.toml"


@pytest.fixture(scope="module")
def model():
    from bmctl.moments import make_moment_model

    return make_moment_model(LAB)


# --- Plant.sample ------------------------------------------------------------------------------
def test_sample_of_more_particles_than_the_plant_has_returns_n():
    """``sample(500)`` of a 200-particle plant returned 200 (its docstring: with replacement if n > M)."""
    from bmctl.plant import make_plant

    plant = make_plant(LAB, seed=0, particles=200)
    s_um, r = plant.sample(500, rng=np.random.default_rng(1))
    assert s_um.shape == (500,) and r.shape == (500,)
    assert set(np.round(s_um, 9)) <= set(np.round(plant.s * 1e6, 9))


def test_sample_of_at_most_m_draws_as_before():
    from bmctl.plant import make_plant

    plant = make_plant(LAB, seed=0, particles=200)
    s_um, _ = plant.sample(150, rng=np.random.default_rng(3))
    k = np.random.default_rng(3).choice(200, size=150, replace=False)
    assert np.array_equal(s_um, plant.s[k] / 1e-6)


# --- Plant.run_schedule ------------------------------------------------------------------------
@pytest.mark.parametrize("segments, every, needle", [
    ([(1.0, 300.0)], 0.0, "record_every_h: must be a finite number of hours > 0"),
    ([(1.0, 300.0)], -1.0, "record_every_h: must be a finite number of hours > 0"),
    ([(-1.0, 300.0)], 0.5, r"segments\[0\]: must be \(hours, rpm\)"),
    ([(1.0, 300.0), (1.0, 300.0, 0.5)], 0.5, r"segments\[1\]: must be \(hours, rpm\)"),
])
def test_run_schedule_refuses_what_run_open_loop_refuses(segments, every, needle):
    from bmctl.loop import run_open_loop
    from bmctl.plant import make_plant

    plant = make_plant(LAB, seed=0, particles=50)
    with pytest.raises(InputError, match=needle):
        plant.run_schedule(segments, every)
    with pytest.raises(InputError, match=needle):
        run_open_loop(plant, segments, every, lambda t, m: None)
    assert plant.t_s == 0.0


# --- make_moment_model -------------------------------------------------------------------------
def _foreign_card(tmp_path):
    """A copy of the lab card with gamma changed, beside a copy of the lab card's coefficients."""
    text = LAB.read_text(encoding="utf-8")
    assert "gamma_per_um2 = 1.82e-4" in text
    card = tmp_path / "mine.toml"
    card.write_text(text.replace("gamma_per_um2 = 1.82e-4", "gamma_per_um2 = 3.0e-4"), encoding="utf-8")
    shutil.copy(LAB.with_name(LAB.stem + ".moments.toml"), tmp_path / "mine.moments.toml")
    return card


def test_make_moment_model_refuses_coefficients_of_another_card_as_for_card_does(tmp_path):
    from bmctl.moments import for_card, make_moment_model

    card = _foreign_card(tmp_path)
    with pytest.raises(InputError) as want:
        for_card(card)
    with pytest.raises(InputError, match="stochastic.gamma_per_um2 0.0003 \\(coefficients: 0.000182\\)") as got:
        make_moment_model(card)
    assert str(got.value).split("; fix:")[0] == str(want.value).split("; fix:")[0]


def test_make_moment_model_takes_a_card_file_without_coefficients_on_the_defaults(tmp_path):
    from bmctl.config import load_card
    from bmctl.moments import default_coeffs, make_moment_model

    card = tmp_path / "bare.toml"
    shutil.copy(LAB, card)
    m = make_moment_model(card)
    assert m.coeffs_source == "defaults" and m.coeffs == default_coeffs(load_card(LAB))


def test_make_moment_model_of_a_card_object_needs_coeffs():
    """A card object silently ran on the built-in defaults (s_mean 23 % off the card's own at 12 h)."""
    from bmctl.config import load_card
    from bmctl.moments import make_moment_model

    with pytest.raises(InputError, match="card alni-1to1-300rpm-lab: make_moment_model: .* pass the card's path"):
        make_moment_model(load_card(LAB))


def test_make_moment_model_defaults_on_request_and_explicit_files_as_given(tmp_path):
    from bmctl.config import load_card
    from bmctl.moments import default_coeffs, make_moment_model

    card = _foreign_card(tmp_path)
    d = make_moment_model(card, coeffs="defaults")
    assert d.coeffs_source == "defaults" and d.coeffs == default_coeffs(load_card(card))
    obj = make_moment_model(load_card(LAB), coeffs="defaults")
    assert obj.coeffs == default_coeffs(load_card(LAB))
    own = make_moment_model(card, coeffs=tmp_path / "mine.moments.toml")  # named: used as given
    assert own.coeffs_source == str(tmp_path / "mine.moments.toml")
    with pytest.raises(InputError, match="coeffs: must be a dict, a coefficient file or \"defaults\""):
        make_moment_model(LAB, coeffs=3)


# --- MomentModel.simulate / step ---------------------------------------------------------------
@pytest.mark.parametrize("U, needle", [
    ([[5000.0, 1.0]], r"U\[0\]: rpm must be a number in \[0, 600\]"),
    ([[300.0, 1.0], [-300.0, 1.0]], r"U\[1\]: rpm must be a number in \[0, 600\]"),
    ([[300.0, 2.0]], r"U\[0\]: milling must be a number in \[0, 1\]"),
    ([[math.nan, 1.0]], r"U\[0\]: rpm"),
    ([[300.0, 1.0, 0.0]], r"U: must be \(rpm, milling\) per interval, shape \(K, 2\)"),
])
def test_simulate_refuses_inputs_out_of_range_or_shape(model, U, needle):
    with pytest.raises(InputError, match=needle):
        model.simulate(model.x0(), U, 0.5)


def test_simulate_and_step_refuse_a_state_of_the_wrong_length(model):
    with pytest.raises(InputError, match=r"x0: must be a state .* shape \(\.\.\., 6\) \(got shape \(5,\)\)"):
        model.simulate(model.x0()[:5], [[300.0, 1.0]], 0.5)
    with pytest.raises(InputError, match=r"^x: must be a state"):
        model.step(model.x0()[:5], [300.0, 1.0], 0.5)


@pytest.mark.parametrize("u, needle", [
    ([5000.0, 1.0], r"^u: rpm"), ([-300.0, 1.0], r"^u: rpm"), ([300.0, 2.0], r"^u: milling"),
    ([300.0, 1.0, 0.0], r"^u: must be \(rpm, milling\)"), ([[300.0, 1.0], [300.0, -1.0]], r"^u\[1\]: milling"),
])
def test_step_refuses_inputs_out_of_range_or_shape(model, u, needle):
    with pytest.raises(InputError, match=needle):
        model.step(model.x0(), u, 0.5)


def test_a_solvers_rounding_at_the_bounds_is_accepted(model):
    """A solver's bound violation (rpm / rpm_max and milling off by ~1e-8) still runs, as in the MPC."""
    top = model.rpm_max
    X = model.simulate(model.x0(), [[top * (1 + 1e-7), 1.0 + 1e-7], [-1e-7, -1e-7]], 0.5)
    assert X.shape == (3, 6) and np.all(np.isfinite(X))
    x = model.step(np.tile(model.x0(), (3, 1)), [top * (1 + 1e-7), 1.0], 0.5)
    assert x.shape == (3, 6) and np.all(np.isfinite(x))
    assert model.simulate(model.x0(), np.zeros((0, 2)), 0.5).shape == (1, 6)


# --- the filters' predict ----------------------------------------------------------------------
def test_check_predict_refuses_an_rpm_above_the_top_speed():
    from bmctl.estimate.filter import check_predict

    with pytest.raises(InputError, match="^u: rpm 5000 exceeds the model's rpm_max 2000"):
        check_predict((5000.0, 1.0), 0.5)
    with pytest.raises(InputError, match="^u: rpm 700 exceeds the model's rpm_max 600"):
        check_predict((700.0, 1.0), 0.5, rpm_max=600.0)
    assert check_predict((600.0 * (1 + 1e-7), 1.0), 0.5, rpm_max=600.0) == 0.5


def test_particle_filter_predict_refuses_an_rpm_above_the_models(model):
    from bmctl.estimate import FilterSettings, ParticleFilter

    pf = ParticleFilter(model, np.random.default_rng(0), FilterSettings(n_particles=50))
    with pytest.raises(InputError, match="^u: rpm 700 exceeds the model's rpm_max 600"):
        pf.predict((700.0, 1.0), 0.5)
    assert pf.t_h == 0.0


# --- ClosedLoop --------------------------------------------------------------------------------
class _Plan:
    def __init__(self, u, status=None):
        from bmctl.control.base import Status

        self.u_apply = u
        self.status = Status("test") if status is None else status


def _loop(plan, particles=50):
    from bmctl.loop import ClosedLoop, LoopConfig
    from bmctl.plant import make_plant

    mill = make_plant(LAB, seed=0, particles=particles)
    return ClosedLoop(mill, FakeSensor(), FakeEstimator(), FakeController(plan), np.random.default_rng(0),
                      LoopConfig(hours=0.5, sample_every_h=0.5))


@pytest.mark.parametrize("u, applied", [((-1e-7, 1.0), (0.0, 1.0)), ((600.0 + 1e-5, 1.0 + 1e-7), (600.0, 1.0))])
def test_a_plan_within_a_solvers_rounding_of_a_bound_runs_at_the_bound(u, applied):
    """rpm -1e-7 passed the plan check, then Plant.advance refused it."""
    lp = _loop(_Plan(u))
    rec = lp.step()
    assert (rec.rpm, rec.milling) == applied and lp.estimator.inputs == [applied]


def test_a_plan_above_the_mills_top_speed_is_refused_before_the_mill_runs():
    lp = _loop(_Plan((5000.0, 1.0)))
    with pytest.raises(ValueError, match="controller.plan: u_apply rpm 5000 exceeds the mill's rpm_max 600"):
        lp.step()
    assert lp.mill.t_s == 0.0 and lp.k == 0


@pytest.mark.parametrize("status", ["ok", None, object()])
def test_a_plan_whose_status_is_no_status_is_refused_naming_the_plan(status):
    plan = _Plan((300.0, 1.0))
    plan.status = status
    lp = _loop(plan)
    with pytest.raises(TypeError, match="controller.plan: status must be a bmctl.control.Status"):
        lp.step()
    assert lp.mill.t_s == 0.0


def test_apply_clips_a_rounding_and_refuses_farther_out():
    lp = _loop(_Plan((300.0, 1.0)))
    lp.apply(-1e-7, 1.0 + 1e-9, 0.05)
    assert lp.estimator.inputs == [(0.0, 1.0)]
    with pytest.raises(InputError, match=r"^rpm: must be in \[0, 600\]"):
        lp.apply(-1.0, 1.0, 0.05)
    with pytest.raises(InputError, match=r"^milling: must be in \[0, 1\]"):
        lp.apply(300.0, 1.5, 0.05)


# --- run_filter --------------------------------------------------------------------------------
def _samples(times):
    from bmctl.estimate.run import Sample

    g = np.random.default_rng(0)
    return [Sample(t, g.lognormal(np.log(40.0), 0.4, 30), g.uniform(0.0, 0.2, 30), source=f"s{k}")
            for k, t in enumerate(times)]


@pytest.mark.parametrize("times, kw, needle", [
    ([2.0, 1.0], {}, "s1: t_h: sample times must increase \\(got 2 then 1\\)"),
    ([1.0, 1.0], {}, "s1: t_h: sample times must increase"),
    ([-1.0, 1.0], {}, "s0: t_h must be a finite number of hours >= 0"),
    ([math.nan], {}, "s0: t_h must be a finite number of hours >= 0"),
    ([1.0], {"max_step_h": 0.0}, "max_step_h: must be a finite number of hours > 0"),
    ([1.0], {"max_step_h": -1.0}, "max_step_h: must be a finite number of hours > 0"),
])
def test_run_filter_refuses_samples_out_of_order_and_a_zero_step(model, times, kw, needle):
    from bmctl.estimate import FilterSettings
    from bmctl.estimate.run import run_filter

    with pytest.raises(InputError, match=needle):
        run_filter(model, _samples(times), [(4.0, 300.0)], FilterSettings(n_particles=50), **kw)


def test_run_filter_refuses_a_sample_before_the_filters_time(model):
    from bmctl.estimate import FilterSettings
    from bmctl.estimate.run import run_filter

    pf, _ = run_filter(model, _samples([1.0]), [(4.0, 300.0)], FilterSettings(n_particles=50))
    with pytest.raises(InputError, match=re.escape("s0: t_h: 0.5 h is before the filter's time, 1 h")):
        run_filter(model, _samples([0.5]), [(4.0, 300.0)], pf=pf)


def test_make_estimator_names_a_bad_kind_count_or_generator():
    import numpy as np

    from bmctl.errors import InputError
    from bmctl.estimate.run import make_estimator
    from bmctl.moments import make_moment_model

    m = make_moment_model(ROOT / "models" / "alni-1to1-300rpm-lab.toml")
    with pytest.raises(InputError, match="kind: the estimator is one of pf, ukf"):
        make_estimator("PF", m, np.random.default_rng(0))
    for n in (15.7, True, "300"):
        with pytest.raises(InputError, match="n_particles: a whole number"):
            make_estimator("pf", m, np.random.default_rng(0), n_particles=n)
    with pytest.raises(TypeError, match="rng: must be a numpy.random.Generator"):
        make_estimator("ukf", m, 0)  # as the particle filter refuses it
    assert make_estimator("pf", m, np.random.default_rng(0), n_particles=300.0).settings.n_particles == 300


def test_a_loop_longer_than_the_longest_batch_and_a_boolean_target_are_refused():
    from bmctl.control.config import target_value
    from bmctl.errors import InputError
    from bmctl.loop import LoopConfig

    assert LoopConfig(hours=1000.0, sample_every_h=1.0).hours == 1000.0
    with pytest.raises(InputError, match="hours: 1e\\+06 h is more than the longest batch"):
        LoopConfig(hours=1e6, sample_every_h=1.0)
    for v in (True, [30.0, True]):
        with pytest.raises(InputError, match="s_mean_um: not a number: True"):
            target_value("s_mean_um", v, "target")
