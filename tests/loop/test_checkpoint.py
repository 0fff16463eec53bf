"""Plain-data checkpoints and the loop's protocols."""

import numpy as np
import pytest

from bmctl.checkpoint import load_state, save_state
from bmctl.errors import InputError
from bmctl.loop import Controller, Estimator, Mill

from ..conftest import ROOT, card_path


@pytest.mark.slow
def test_round_trip_restores_generators_exactly(tmp_path):
    from bmctl.plant import make_plant

    plant = make_plant(card_path("alni-1to1-300rpm-lab"), seed=3, particles=300)
    plant.advance(300.0, 0.1)
    save_state(tmp_path / "c.npz", {"plant": plant.get_state()})
    a = make_plant(card_path("alni-1to1-300rpm-lab"), seed=99, particles=300)
    a.set_state(load_state(tmp_path / "c.npz")["plant"])
    plant.advance(300.0, 0.1)
    a.advance(300.0, 0.1)
    assert np.array_equal(plant.s, a.s) and np.array_equal(plant.r, a.r) and plant.temperature_c == a.temperature_c


@pytest.mark.parametrize("content", [b"", b"garbage", b"PK\x03\x04garbage"])
def test_damaged_checkpoint_is_one_input_error(tmp_path, content):
    p = tmp_path / "checkpoint.npz"
    p.write_bytes(content)
    with pytest.raises(InputError, match="checkpoint.npz"):
        load_state(p)


def test_objects_are_not_plain_data(tmp_path):
    with pytest.raises(TypeError, match="plain data"):
        save_state(tmp_path / "c.npz", {"x": object()})


@pytest.mark.slow
def test_protocols_fit_the_shipped_objects():
    from bmctl.control import make_controller
    from bmctl.estimate import FilterSettings, ParticleFilter
    from bmctl.moments import make_moment_model
    from bmctl.plant import make_plant

    lab = card_path("alni-1to1-300rpm-lab")
    model = make_moment_model(lab)
    assert isinstance(make_plant(lab, seed=0, particles=10), Mill)
    assert isinstance(ParticleFilter(model, np.random.default_rng(0), FilterSettings(n_particles=50)), Estimator)
    for cfg in ("mpc-fast", "lqr-baseline", "recipe-400rpm-30-10"):
        assert isinstance(make_controller(ROOT / "controllers" / f"{cfg}.toml", model), Controller)
