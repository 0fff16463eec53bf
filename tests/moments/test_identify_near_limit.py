"""Identification of a card whose gamma or delta lies near its field's upper limit (1 µm^-2).

The training plants off the card multiply gamma and delta by identify.TRAIN_FACTORS (1.15, 0.85 and the
reverse) and the off-card check by identify.FACTORS (1.3, 0.7 and the reverse). On a card with gamma or
delta above 1/1.3 (a calibrated card, a hand-written one) a factor took the plant past the field's limit
and the plant card failed validation with a traceback. Such a factor is now cut so the plant sits at the
limit, and the factor recorded (Spec.factors, the model's p) is the plant's own.
"""

import numpy as np
import pytest

from bmctl.cli import main
from bmctl.config import load_card, with_factors
from bmctl.moments import coeffs as cf
from bmctl.moments import identify as ident
from bmctl.moments.forcard import status

from ..conftest import CARDS, card_path

LAB = card_path("alni-1to1-300rpm-lab")


def _near(gamma=None, delta=None):
    card = load_card(LAB)
    upd = {k: v for k, v in (("gamma_per_um2", gamma), ("delta_per_um2", delta)) if v is not None}
    return card.model_copy(update={"stochastic": card.stochastic.model_copy(update=upd)})


def _off_specs(card):
    """(spec, the module's factors it comes from) of every plant off the card: training (full and quick
    designs) and the off-card check."""
    train = [s for q in (False, True) for s in ident.design(card, 0, quick=q) if s.factors != (1.0, 1.0)]
    return [(s, ident.TRAIN_FACTORS) for s in train] + [(s, ident.FACTORS) for s in ident.off_card_design(card)]


@pytest.mark.parametrize("name", CARDS)
def test_shipped_cards_keep_the_full_factors(name):
    """Every shipped card is far from the limit: the design's factors are exactly the module's."""
    card = load_card(card_path(name))
    train = {s.factors for s in ident.design(card, 0) if s.factors != (1.0, 1.0)}
    assert train == set(ident.TRAIN_FACTORS)
    assert [s.factors for s in ident.off_card_design(card)] == list(ident.FACTORS)
    assert [s.name for s in ident.off_card_design(card)] == ["recipe-g1.3-d0.7", "recipe-g0.7-d1.3"]
    for f in ident.TRAIN_FACTORS + ident.FACTORS:
        assert ident.plant_factors(card, f) == f


@pytest.mark.parametrize("gamma, delta", [(0.95, None), (None, 0.95), (0.9, 0.8), (1.0, 1.0), (0.8, None)])
def test_plants_of_a_card_near_the_limit_are_valid_cards_at_the_limit(gamma, delta):
    card = _near(gamma, delta)
    g0, d0 = card.stochastic.gamma_per_um2, card.stochastic.delta_per_um2
    specs = _off_specs(card)
    assert len(specs) == 2 * (1 + ident.N_RANDOM_OFF_CARD) + 2 * 2 + len(ident.FACTORS)
    for s, table in specs:
        plant = with_factors(card, *s.factors)  # raised a ValidationError (gamma 1.0925 for 0.95 x 1.15)
        g, d = plant.stochastic.gamma_per_um2, plant.stochastic.delta_per_um2
        assert 0 < g <= 1.0 and 0 < d <= 1.0
        # the recorded factor is the plant's own: plant value = card value x factor, as the model's p
        assert g == g0 * s.factors[0] and d == d0 * s.factors[1]
        assert f"-g{s.factors[0]:g}-d{s.factors[1]:g}" in s.name
        down = 0 if s.factors[0] < 1 else 1  # the factor below 1 is never cut
        full = next(f for f in table if f[down] == s.factors[down])
        for k, (v0, got, want) in enumerate(zip((g0, d0), s.factors, full)):
            if v0 * want <= 1.0:
                assert got == want  # a factor that keeps the plant valid is untouched
            else:
                assert 1.0 <= got < want  # cut, never below the card
                assert (g, d)[k] == pytest.approx(1.0, rel=0, abs=1e-15)  # the plant sits at the limit


def test_near_limit_design_is_otherwise_unchanged():
    """Only the cut factors (and the names that print them) differ from the lab card's design."""
    lab, near = load_card(LAB), _near(0.95)
    for a, b in zip(ident.design(lab, 0), ident.design(near, 0)):
        assert a.inputs == b.inputs and a.prefix == b.prefix and a.factors[1] == b.factors[1]
    assert [s.name for s in ident.off_card_design(near)] == ["recipe-g1.05263-d0.7", "recipe-g0.7-d1.3"]


def test_plant_runs_of_a_near_limit_card_record_the_plants_factors():
    """The plant runs that raised (every off-card spec, a few particles, one seed)."""
    card = _near(0.95, 0.9)
    specs = [s for s in ident.design(card, 0, quick=True) if s.factors != (1.0, 1.0)] + ident.off_card_design(card)
    out = ident.run_experiments(card, specs, [1000], 200)
    assert [e.name for e in out] == [s.name for s in specs]
    for e, s in zip(out, specs):
        assert tuple(e.p) == s.factors and np.all(np.isfinite(e.Y))


def test_identify_a_near_limit_card_end_to_end(tmp_path, capsys, monkeypatch):
    """`bmctl identify --quick` on a hand-written card with gamma 0.95: real plant runs and validation, the fit
    replaced by the built-in defaults (what is checked is the design, not the fit); it used to end in a
    pydantic traceback at the first off-card plant."""
    from bmctl.moments.model import default_coeffs

    def no_fit(model, train, **kw):
        c = default_coeffs(model.card)
        return ident.FitResult(c, 1.0, 1.0, 0, 0.0, "stand-in", start="the built-in defaults",
                               tried=[{"start": "defaults", "cost_initial": 1.0, "cost_final": 1.0, "jacobians": 0}])

    monkeypatch.setattr(ident, "fit", no_fit)
    p = tmp_path / "near.toml"
    p.write_text(LAB.read_text(encoding="utf-8").replace("gamma_per_um2 = 1.82e-4", "gamma_per_um2 = 0.95"), encoding="utf-8")
    rc = main(["identify", str(p), "--quick", "--quiet", "--workers", "0", "--particles", "200",
               "--random-schedules", "0", "--heldout", "1", "--seeds", "1", "--start", "defaults"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    assert "recipe-g1.05263-d0.7" in cap.out and "recipe-g0.7-d1.3" in cap.out
    st = status(load_card(p), p)
    assert st.state == "match"
    assert cf.coeffs_path(p).exists()


@pytest.mark.parametrize("n", [1, 2, 4, 10, 11, 12, 64])
@pytest.mark.parametrize("quick", [False, True])
def test_held_out_plants_are_never_training_plants(n, quick):
    from bmctl.moments.identify import plant_seeds

    train, valid = plant_seeds(3, n, quick)
    assert len(train) == n and len(valid) == (2 if quick else 3)
    assert not set(train) & set(valid), (train, valid)
    if n <= 10:  # the shipped cards' seeds (4): held-out on 11-13 as identified
        assert valid == [3011, 3012, 3013][:len(valid)]
