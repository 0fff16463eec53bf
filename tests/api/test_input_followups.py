"""Input checks where the public API is entered, following up the earlier gaps: the moment model's
``rhs`` and ``event_counts``, an estimator's given initial state ``x0``, ``Raster.from_particles``
called directly, and ``make_plant`` given something that is neither a card path nor a card.
Valid inputs give the same numbers as before (the checks only refuse)."""

from pathlib import Path

import numpy as np
import pytest

from bmctl.config import load_card
from bmctl.errors import InputError
from bmctl.estimate import FilterSettings, ParticleFilter
from bmctl.estimate.likelihood import LawSettings, Raster, check_particles
from bmctl.moments import make_moment_model
from bmctl.plant import make_plant

CARD = "models/alni-1to1-300rpm-lab.toml"


@pytest.fixture(scope="module")
def model():
    return make_moment_model(CARD)


def _with(x, col, v):
    x = np.array(x, dtype=float)
    x[col] = v
    return x


# --- 1. MomentModel.rhs and MomentModel.event_counts ----------------------------------------------
BAD_STATES = [
    (lambda x: _with(x, 0, np.nan), r"x0?: s_mean_um must be finite"),
    (lambda x: _with(x, 5, 1.5), r"x0?: hardening must be in \[0, 1\]"),
    (lambda x: _with(x, 4, -300.0), r"x0?: temperature_c must be >= -273.15"),
    (lambda x: x[:5], r"x0?: must be .*state"),
]


@pytest.mark.parametrize("bad,msg", BAD_STATES)
def test_rhs_refuses_a_bad_state(model, bad, msg):
    with pytest.raises(InputError, match=msg.replace("x0?", "x")):
        model.rhs(bad(model.x0()), [300.0, 1.0])


@pytest.mark.parametrize("u,msg", [([300.0, 2.0], r"u: milling must be"), ([-5.0, 1.0], r"u: rpm must be"),
                                   ([300.0], r"u: must be \(rpm, milling\)")])
def test_rhs_refuses_bad_inputs(model, u, msg):
    with pytest.raises(InputError, match=msg):
        model.rhs(model.x0(), u)


@pytest.mark.parametrize("p", [[1.0, -1.0], [np.nan, 1.0], [1.0]])
def test_rhs_refuses_bad_params(model, p):
    with pytest.raises(InputError, match=r"^p: "):
        model.rhs(model.x0(), [300.0, 1.0], p)


def test_rhs_of_valid_inputs_unchanged(model):
    x = model.x0()
    a = model.rhs(x, [300.0, 1.0])
    b = model.rhs(np.tile(x, (3, 1)), np.tile([300.0, 0.5], (3, 1)), [1.0, 1.0])
    assert a.shape == (6,) and b.shape == (3, 6) and np.all(np.isfinite(a)) and np.all(np.isfinite(b))
    import casadi as ca  # the symbolic path is not checked

    xs, us, ps = ca.SX.sym("x", 6), ca.SX.sym("u", 2), ca.SX.sym("p", 2)
    assert model.rhs(xs, us, ps, xp=ca).shape == (6, 1)


@pytest.mark.parametrize("bad,msg", BAD_STATES)
def test_event_counts_refuses_a_bad_x0(model, bad, msg):
    with pytest.raises(InputError, match=msg.replace("x0?", "x0")):
        model.event_counts(bad(model.x0()), [[300.0, 1.0]], 1.0)


def test_event_counts_refuses_a_batch_of_states(model):
    with pytest.raises(InputError, match=r"x0: must be one state"):
        model.event_counts(np.tile(model.x0(), (6, 1)), [[300.0, 1.0]], 1.0)


@pytest.mark.parametrize("U,msg", [([[300.0, 1.5]], r"U\[0\]: milling must be"),
                                   ([[300.0, 1.0], [1e6, 1.0]], r"U\[1\]: rpm must be"),
                                   ([[300.0, 1.0, 0.0]], r"U: must be \(rpm, milling\)")])
def test_event_counts_refuses_bad_inputs(model, U, msg):
    with pytest.raises(InputError, match=msg):
        model.event_counts(model.x0(), U, 1.0)


@pytest.mark.parametrize("p", [[1.0, -1.0], [np.inf, 1.0], [[1.0, 1.0]]])
def test_event_counts_refuses_bad_params(model, p):
    with pytest.raises(InputError, match=r"^p: "):
        model.event_counts(model.x0(), [[300.0, 1.0]], 1.0, p)


def test_event_counts_of_valid_inputs_run(model):
    C = model.event_counts(model.x0(), [[300.0, 1.0], [0.0, 1.0]], 1.0, [1.0, 1.0])
    assert C.shape == (2, 2) and C[0, 0] > 1 and C[1, 0] < 1e-4


# --- 2. the estimators' initial state ------------------------------------------------------------
def _make(kind, model, x0):
    if kind == "pf":
        return ParticleFilter(model, np.random.default_rng(0), FilterSettings(n_particles=20), x0=x0)
    from bmctl.estimate.ukf import UKFEstimator

    return UKFEstimator(model, np.random.default_rng(0), x0=x0)


@pytest.mark.parametrize("kind", ["pf", "ukf"])
@pytest.mark.parametrize("bad,msg", BAD_STATES)
def test_estimators_refuse_a_bad_x0(model, kind, bad, msg):
    with pytest.raises(InputError, match=msg.replace("x0?", "x0")):
        _make(kind, model, bad(model.x0()))


@pytest.mark.parametrize("kind", ["pf", "ukf"])
def test_estimators_refuse_an_x0_that_is_not_numbers(model, kind):
    with pytest.raises(TypeError, match=r"x0: must be an array of numbers"):
        _make(kind, model, {"s_mean_um": 40.0})


@pytest.mark.parametrize("kind", ["pf", "ukf"])
def test_estimators_given_the_default_x0_match_the_default(model, kind):
    a, b = _make(kind, model, None), _make(kind, model, list(model.x0()))
    assert np.array_equal(a.estimate().mean, b.estimate().mean)


# --- 3. Raster.from_particles called directly -------------------------------------------------------
@pytest.mark.parametrize("s,r", [([], []), ([10.0, 20.0], [0.1]), ([np.nan], [0.1]), ([-1.0], [0.1]),
                                 ([0.0], [0.1]), ([10.0], [1.0]), ([10.0], [np.nan]), ([10.0], [-0.1])])
def test_raster_from_particles_refuses_as_check_particles(s, r):
    s, r = np.asarray(s, dtype=float), np.asarray(r, dtype=float)
    with pytest.raises(InputError) as want:
        check_particles(s, r, "s_um, r")
    with pytest.raises(InputError) as got:
        Raster.from_particles(s, r, LawSettings())
    assert str(got.value) == str(want.value)


# --- 4. make_plant given neither a card path nor a card ---------------------------------------------
@pytest.mark.parametrize("card", [{"mill": {}}, 3, None, [CARD]])
def test_make_plant_refuses_a_card_of_another_type(card):
    with pytest.raises(TypeError, match=r"card: must be a model card path .* or a ModelCard object \(got "):
        make_plant(card, seed=0, particles=50)


def test_make_plant_takes_a_path_a_str_and_a_card():
    for card in (CARD, Path(CARD), load_card(CARD)):
        assert make_plant(card, seed=0, particles=50, engine="numpy").M == 50
