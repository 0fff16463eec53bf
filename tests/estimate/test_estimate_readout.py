"""When the particle filter draws the moments' deferred noise (``moment_noise_at``).

The process noise deferred since the last update is what the next sample's guided proposal
draws. With ``moment_noise_at = "sample"`` a read-out between the two neither spends it nor
advances the filter's generator, so the filter after ``predict, estimate, update`` is the filter
after ``predict, update``, and a read-out shows the noise (its intervals are wider than the bare
particles'); a vial reading leaves the moments' noise deferred too. ``"update"`` (the default)
spends it at every read and update.
"""

from __future__ import annotations

import numpy as np
import pytest

from bmctl.estimate.filter import FilterSettings, ParticleFilter

from ..conftest import card_path

LAB = str(card_path("alni-1to1-300rpm-lab"))


@pytest.fixture(scope="module")
def model():
    from bmctl.moments.model import make_moment_model

    return make_moment_model(LAB)


def _sample(seed: int, median_um: float = 40.0, n: int = 300):
    g = np.random.default_rng(seed)
    return g.lognormal(np.log(median_um), 0.45, n), g.uniform(0.02, 0.2, n)


def _run(model, read: bool, at: str = "sample"):
    pf = ParticleFilter(model, np.random.default_rng(5), FilterSettings(n_particles=300, moment_noise_at=at))
    pf.predict((300.0, 1.0), 1.0)
    if read:
        pf.estimate()
        pf.estimate()
    s_um, r = _sample(1)
    return pf, pf.update(s_um, r, temperature_c=55.0)


def test_a_read_before_a_sample_changes_nothing(model):
    plain, est_plain = _run(model, read=False)
    read, est_read = _run(model, read=True)
    for a, b in zip(plain.get_state().values(), read.get_state().values()):
        if isinstance(a, np.ndarray):
            assert np.array_equal(a, b)
    assert est_read.ess == est_plain.ess
    assert np.array_equal(est_read.mean, est_plain.mean)


def test_a_read_spends_the_noise_by_default(model):
    """The default keeps the filter's long-standing behaviour: a read draws the deferred noise
    from its prior, and the sample after it has none left to guide (fewer particles survive)."""
    _, est_plain = _run(model, read=False, at="update")
    pf, est_read = _run(model, read=True, at="update")
    assert pf.pending_h == 0.0 and est_read.ess < 0.5 * est_plain.ess


def test_the_read_out_includes_the_deferred_noise_and_leaves_it_deferred(model):
    pf = ParticleFilter(model, np.random.default_rng(7), FilterSettings(n_particles=400, moment_noise_at="sample"))
    pf.predict((300.0, 1.0), 2.0)
    bare = pf._summary()
    rng_before = pf.rng.bit_generator.state
    est = pf.estimate()
    assert pf.pending_h == 2.0 and pf.rng.bit_generator.state == rng_before
    k = list(est.names).index("s_mean_um")
    assert est.q95[k] - est.q05[k] > bare.q95[k] - bare.q05[k]
    again = pf.estimate()
    assert np.array_equal(again.mean, est.mean)  # the same read-out from the same state


def _reading_then_sample(model, at: str):
    pf = ParticleFilter(model, np.random.default_rng(11), FilterSettings(n_particles=500, moment_noise_at=at))
    pf.predict((300.0, 1.0), 1.0)
    reading = pf.update(temperature_c=pf.reading_prediction()[0])
    s_um, r = _sample(2, median_um=36.0)
    return pf, reading, pf.update(s_um, r)


def test_moment_noise_at_sample_keeps_it_past_a_reading(model):
    """A reading alone cannot guide the moments' noise: with ``moment_noise_at="sample"`` it stays
    deferred for the sample that follows, whose guided proposal then keeps more particles alive than
    the reweighting of noise already spent unguided ("update")."""
    pf, reading, _ = _reading_then_sample(model, "sample")
    assert pf.pending_model_h == 0.0  # spent by the sample
    spent, _, after_spent = _reading_then_sample(model, "update")
    kept, _, after_kept = _reading_then_sample(model, "sample")
    assert after_kept.ess > 2 * after_spent.ess
    k = list(reading.names).index("s_mean_um")
    bare = ParticleFilter(model, np.random.default_rng(11), FilterSettings(n_particles=500, moment_noise_at="sample"))
    bare.predict((300.0, 1.0), 1.0)
    bare.update(temperature_c=bare.reading_prediction()[0])
    assert bare.pending_model_h == 1.0  # the milled hour's noise still deferred after the reading
    shown, plain = bare.estimate(), bare._summary()
    assert shown.q95[k] - shown.q05[k] > plain.q95[k] - plain.q05[k]  # and shown in the estimate


def test_moment_noise_at_update_is_the_default_and_spends_it():
    assert FilterSettings().moment_noise_at == "update"
    with pytest.raises(Exception, match="moment_noise_at"):
        FilterSettings(moment_noise_at="later")
