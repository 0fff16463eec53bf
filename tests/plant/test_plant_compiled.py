"""The compiled (numba) plant engine: same seed, same trajectory as the numpy engine, to the last bit,
on every CPU (the numpy engine calls the C library's exp, log1p, cbrt and pow, as the compiled code
does, not numpy's SIMD versions that differ in the last bit on x86-64 with AVX-512).
"""

import numpy as np
import pytest

from bmctl.config import card_schedule, load_card
from bmctl.errors import InputError
from bmctl.plant import plant as plant_module
from bmctl.plant.kernels import constant_agglomeration
from bmctl.plant.kinematics import kinematics
from bmctl.plant.plant import Plant
from bmctl.validation.engine import AuditedPlant

from tests.conftest import CARDS, card_path


@pytest.fixture(scope="module")
def compiled():
    from bmctl.plant._compiled import compile_now

    compile_now()  # in this process (loads the cache when warm)


def _pair(card, seed, M):
    return (Plant(card, np.random.default_rng(seed), M, engine="numpy"),
            Plant(card, np.random.default_rng(seed), M, engine="numba"))


def _assert_same(a: Plant, b: Plant):
    # to the last bit on every CPU: the numpy engine's exp, log1p, cbrt and pow are the C library's, as
    # the compiled engine's (bmctl.physics.libm; numpy's own SIMD versions differ in the last bit)
    np.testing.assert_array_equal(a.s, b.s)
    np.testing.assert_array_equal(a.r, b.r)
    assert (a.counts.impacts, a.counts.bonds, a.counts.fractures) == \
        (b.counts.impacts, b.counts.bonds, b.counts.fractures)
    assert a.temperature_C == b.temperature_C and a.hardening == b.hardening
    for qa, qb in zip(a._queue, b._queue):
        np.testing.assert_array_equal(qa, qb)
    assert a.rng.bit_generator.state == b.rng.bit_generator.state


@pytest.mark.slow
@pytest.mark.parametrize("name", CARDS)
def test_engines_give_identical_moments_for_the_same_seed(compiled, name):
    card = load_card(card_path(name))
    a, b = _pair(card, 7, 1500)
    assert b._compiled_step() and not a._compiled_step()
    ra = a.run_schedule(card_schedule(card, 3.0), record_every_h=0.5)
    rb = b.run_schedule(card_schedule(card, 3.0), record_every_h=0.5)
    assert a.counts.bonds > 100 and a.counts.fractures > 100  # the events ran
    assert [x.moments for x in ra] == [x.moments for x in rb]
    _assert_same(a, b)


@pytest.mark.slow
def test_engines_agree_across_rests_speed_changes_and_restore(compiled):
    card = load_card(card_path("alni-1to1-300rpm-lab"))
    a, b = _pair(card, 11, 800)
    for rpm, h in [(300.0, 0.7), (0.0, 0.3), (500.0, 0.4)]:
        a.advance(rpm, h, milling=0.8)
        b.advance(rpm, h, milling=0.8)
        _assert_same(a, b)
    snap = a.snapshot()
    b.restore(snap)
    a.advance(350.0, 0.5)
    b.advance(350.0, 0.5)
    _assert_same(a, b)


@pytest.mark.slow
def test_single_batch_with_a_queue_matches(compiled):
    # Plant._impacts on its own: n new impacts, one round, the rest stays queued (then every round)
    card = load_card(card_path("alni-1to1-300rpm-lab"))
    a, b = _pair(card, 3, 300)
    kin = kinematics(card, 400.0)
    for n, flush in [(120, False), (80, False), (0, True)]:
        a._impacts(kin, n, flush)
        b._impacts(kin, n, flush)
        _assert_same(a, b)
    assert a.counts.impacts == 200 and a._queue[0].size == 0


def test_other_kernels_and_audited_subclasses_run_the_numpy_code():
    card = load_card(card_path("alni-1to1-300rpm-lab"))
    swapped = Plant(card, np.random.default_rng(0), 100, kernels=constant_agglomeration(1e-12, 1e9))
    audited = AuditedPlant(card, np.random.default_rng(0), 100)
    assert not swapped._compiled_step() and not audited._compiled_step()


def test_unknown_engine_is_an_input_error():
    with pytest.raises(InputError, match="engine"):
        Plant(load_card(card_path("alni-1to1-300rpm-lab")), np.random.default_rng(0), 100, engine="cuda")


def test_cold_cache_runs_numpy_code_and_compiles_in_background(monkeypatch):
    from bmctl.plant import _compiled as cc

    started = []
    monkeypatch.setattr(cc, "cache_is_warm", lambda: False)
    monkeypatch.setattr(cc, "compile_in_background", lambda: started.append(1) or True)
    monkeypatch.setattr(plant_module, "_READY", {"warm": False, "checked": -np.inf})
    monkeypatch.delenv("BMCTL_COMPILE", raising=False)
    card = load_card(card_path("alni-1to1-300rpm-lab"))
    a, b = _pair(card, 5, 200)
    b.advance(300.0, 0.2)
    a.advance(300.0, 0.2)
    assert started == [1] and not b._compiled_step()
    _assert_same(a, b)


def test_card_samplers_choose_the_kernels_and_bad_values_name_the_field(tmp_path):
    from bmctl.config import load_card

    card = load_card(card_path("alni-1to1-300rpm-lab"))
    assert Plant(card, np.random.default_rng(0), 100).kernels.samplers == "tabulated"
    exact = card.model_copy(update={"simulation": card.simulation.model_copy(update={"samplers": "exact"})})
    assert Plant(exact, np.random.default_rng(0), 100).kernels.samplers == "exact"
    text = card_path("alni-1to1-300rpm-lab").read_text(encoding="utf-8").replace("[simulation]", '[simulation]\nsamplers = "fast"')
    bad = tmp_path / "bad.toml"
    bad.write_text(text, encoding="utf-8")
    with pytest.raises(InputError, match="simulation.samplers"):
        load_card(bad)


@pytest.mark.slow
def test_engines_agree_with_the_exact_samplers(compiled):
    card = load_card(card_path("alni-1to1-300rpm-lab"))
    card = card.model_copy(update={"simulation": card.simulation.model_copy(update={"samplers": "exact"})})
    a, b = _pair(card, 13, 800)
    assert b._compiled_step() and a.kernels.samplers == b.kernels.samplers == "exact"
    for rpm, h in [(300.0, 0.6), (450.0, 0.4)]:
        a.advance(rpm, h)
        b.advance(rpm, h)
        _assert_same(a, b)
    assert a.counts.bonds > 10 and a.counts.fractures > 10
