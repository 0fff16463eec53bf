"""Identification's plant runs on Dask: same numbers serially and on workers, seeds kept."""

import numpy as np
import pytest

from bmctl.config import load_card
from bmctl.moments import identify as ident
from bmctl.parallel import auto_workers, close_client

from ..conftest import card_path

LAB = card_path("alni-1to1-300rpm-lab")


def _specs(card):
    """A constant run, a branch (prefix, snapshot, branch) and an off-card plant: every path of run_experiments."""
    return [ident.Spec("const", [(300.0, 1.0)] * 2),
            ident.Spec("branch", [(150.0, 1.0)] * 2, [(450.0, 1.0)]),
            ident.Spec("off", [(300.0, 1.0)] * 2, factors=(1.3, 0.7))]


@pytest.mark.slow
def test_run_experiments_same_numbers_serial_and_on_two_workers():
    from distributed import Client, LocalCluster

    card = load_card(LAB)
    serial = ident.run_experiments(card, _specs(card), [3, 4], 200)
    client = Client(LocalCluster(n_workers=2, processes=False, threads_per_worker=1, dashboard_address=":0",
                                 silence_logs=40))
    try:
        dask = ident.run_experiments(card, _specs(card), [3, 4], 200, client=client)
    finally:
        close_client(client)
    for a, b in zip(serial, dask):
        assert a.name == b.name
        for f in ("Y", "S", "events", "U", "p"):
            assert np.array_equal(getattr(a, f), getattr(b, f)), (a.name, f)


def test_run_experiments_plants_are_make_plant_of_each_seed():
    """Each run is the plant of ``make_plant(seed=sd)`` (a branch: run the prefix, then the inputs)."""
    from bmctl.config import with_factors
    from bmctl.plant import make_plant

    card = load_card(LAB)
    specs = _specs(card)
    got = ident.run_experiments(card, specs, [3, 4], 200)
    for spec, e in zip(specs, got):
        c = card if spec.factors == (1.0, 1.0) else with_factors(card, *spec.factors)
        finals = []
        for sd in (3, 4):
            plant = make_plant(c, seed=sd, particles=200)
            for rpm, duty in spec.prefix + spec.inputs:
                plant.advance(rpm, ident.DT_H, duty)
            finals.append(plant.moments()["s_mean_um"])
        assert np.isclose(e.Y[-1, 0], np.mean(finals), rtol=1e-12, atol=0.0), spec.name


def test_small_ensembles_run_serially():
    assert auto_workers(3, 1e4) == 0 and auto_workers(100, 1.0) == 0
    assert auto_workers(100, 1e4) >= 1 and auto_workers(100, 1e4, workers=2) == 2
    assert auto_workers(100, 1e4, scheduler="tcp://h:8786") is None


def _refuse(task, rng):
    from bmctl.errors import InputError

    raise InputError(f"card x: task {task} refused")


def test_a_task_refused_on_a_worker_is_one_line_not_worker_tracebacks(capfd):
    """A card refused inside a plant run on Dask (e.g. runaway bonding in `bmctl identify --workers 2`) printed a
    "Compute Failed" log with a traceback per task from the workers before bmctl's one line."""
    from bmctl.errors import InputError
    from bmctl.parallel import client_for, map_seeded

    client = client_for(None, 2)  # worker processes: their logs reach stderr
    try:
        with pytest.raises(InputError, match="refused"):
            map_seeded(_refuse, [1, 2], [np.random.SeedSequence(1), np.random.SeedSequence(2)], client)
    finally:
        close_client(client)
    err = capfd.readouterr().err
    assert "Compute Failed" not in err and "Traceback" not in err
