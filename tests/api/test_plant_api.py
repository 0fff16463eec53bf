"""make_plant / Plant as a library user calls them: a seed, a generator, a particle count or a
sample size of the wrong kind is refused naming the argument, not passed to numpy (or, for
``particles=0``, silently replaced by the card's default)."""

import numpy as np
import pytest

from bmctl.errors import InputError
from bmctl.plant import default_card, make_plant


@pytest.fixture(scope="module")
def card():
    return default_card()


@pytest.mark.parametrize("seed", [-1, 1.5, "a", True])
def test_a_seed_that_is_not_a_non_negative_integer_is_named(card, seed):
    with pytest.raises(InputError, match="seed: must be a non-negative integer"):
        make_plant(card, seed=seed, particles=50)


def test_a_seed_and_an_equal_generator_give_the_same_plant(card):
    a = make_plant(card, seed=3, particles=50)
    b = make_plant(card, rng=np.random.default_rng(3), particles=50)
    assert np.array_equal(a.s, b.s) and np.array_equal(a.r, b.r)


def test_an_int_as_rng_is_refused_naming_rng(card):
    with pytest.raises(TypeError, match="rng: must be a numpy.random.Generator"):
        make_plant(card, rng=5, particles=50)


@pytest.mark.parametrize("particles,msg", [(0, "must be >= 2"), (2.7, "must be a whole number")])
def test_particles_zero_or_fractional_is_refused_not_replaced(card, particles, msg):
    with pytest.raises(InputError, match=f"particles: {msg}"):
        make_plant(card, seed=0, particles=particles)


@pytest.mark.parametrize("n", [2.5, "10", 0])
def test_sample_size_must_be_a_whole_number(card, n):
    plant = make_plant(card, seed=0, particles=50)
    with pytest.raises(InputError, match="sample: n must be a whole number >= 1"):
        plant.sample(n)


def test_sample_rng_must_be_a_generator(card):
    plant = make_plant(card, seed=0, particles=50)
    with pytest.raises(TypeError, match="sample: rng must be a numpy.random.Generator"):
        plant.sample(10, rng=1)


@pytest.mark.parametrize("drop", ["s", "rng", "counts", "queue"])
def test_set_state_of_an_incomplete_state_is_refused_and_changes_nothing(drop):
    from bmctl.plant import make_plant

    plant = make_plant("models/alni-1to1-300rpm-lab.toml", seed=1, particles=300)
    fresh = plant.get_state()
    plant.advance(300.0, 0.2)
    before = plant.get_state()
    bad = {k: v for k, v in fresh.items() if k != drop}
    with pytest.raises(ValueError, match=f"state: lacks {drop}"):
        plant.set_state(bad)
    after = plant.get_state()
    assert np.array_equal(after["s"], before["s"]) and after["t_s"] == before["t_s"]
    assert after["rng"] == before["rng"]
