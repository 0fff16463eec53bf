"""Shared physics: pinned quadrature constants, the impact laws the plant and the moment model
share, and the import boundaries (the moment model and the estimator do not need the plant)."""

import math
import subprocess
import sys

import numpy as np
import pytest

from bmctl.physics import constants as C
from bmctl.physics import impacts
from bmctl.physics.kinematics import abs_diff_mean, kinematics, loss_ratio_mean

from ..conftest import ROOT, card_path


@pytest.mark.slow
def test_pinned_quadrature_constants_recompute():
    assert abs_diff_mean() == pytest.approx(C.MEAN_ABS_DIFF_GAMMA15, rel=1e-13)
    assert loss_ratio_mean() == pytest.approx(C.MEAN_LOSS_RATIO, rel=1e-13)
    # E|X - Y| for iid Gamma(3/2, 1) is 4/pi in closed form
    assert C.MEAN_ABS_DIFF_GAMMA15 == pytest.approx(4 / math.pi, rel=1e-12)


def test_impact_laws_draw_as_the_plant_does():
    from bmctl.plant import events as ev
    from bmctl.plant import kernels as kn

    for a, b in ((impacts.sample_impact_energies, ev.sample_impact_energies), (impacts.sample_zeta, ev.sample_zeta),
                 (impacts.sample_xi, ev.sample_xi)):
        x = a(np.random.default_rng(1), 2.1, 500)
        y = b(np.random.default_rng(1), 2.1, 500)
        assert np.array_equal(np.asarray(x), np.asarray(y))
    assert impacts.dissipation_coefficients(2.17, 1.72) == kn.dissipation_coefficients(2.17, 1.72)
    assert np.array_equal(impacts.sample_impact_angles(np.random.default_rng(2), 0.8, 0.6, 100),
                          kn.sample_impact_angles(np.random.default_rng(2), 0.8, 0.6, 100))


@pytest.mark.parametrize("rpm", [0.0, 150.0, 300.0, 600.0])
def test_hit_rate_is_the_plant_kernels_rate(rpm):
    from bmctl.plant import make_plant

    plant = make_plant(card_path("alni-1to1-300rpm-lab"), seed=0, particles=10)
    kin = kinematics(plant.card, rpm)
    st = plant.card.stochastic
    assert impacts.hit_rate(st.alpha, st.beta, kin) == plant.hit_rate(kin)


def _run(code: str) -> str:
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True).stdout


@pytest.mark.slow
def test_moments_and_estimate_do_not_import_the_plant():
    out = _run("import bmctl.moments, bmctl.estimate, sys; print([m for m in sys.modules if m.startswith('bmctl.plant')])")
    assert out.strip() == "[]"


@pytest.mark.slow
def test_plant_import_does_not_integrate():
    out = _run("import bmctl.plant, sys; print('scipy.integrate' in sys.modules)")
    assert out.strip() == "False"
