"""MomentModel.step / simulate / linearize / loglik refuse states, multipliers, inputs and samples that
are not what their docstrings allow, naming the argument, instead of NaN states, IndexErrors or raw
casadi errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bmctl.errors import InputError

from ..conftest import card_path

LAB = str(card_path("alni-1to1-300rpm-lab"))
U = [300.0, 1.0]


@pytest.fixture(scope="module")
def model():
    from bmctl.moments import make_moment_model

    return make_moment_model(LAB)


def _x(model, i, v):
    x = model.x0().copy()
    x[i] = v
    return x


# --- multipliers -------------------------------------------------------------------------------
@pytest.mark.parametrize("p, needle", [
    ((math.nan, 1.0), r"^p: gamma_mult must be a finite number >= 0 \(got nan\)"),
    ((math.inf, 1.0), r"^p: gamma_mult must be a finite number >= 0 \(got inf\)"),
    ((1.0, -1.0), r"^p: delta_mult must be a finite number >= 0 \(got -1\)"),
    ((1.0, 1.0, -0.5), r"^p: energy_mult must be a finite number >= 0"),
    ([1.0], r"^p: must be \(gamma_mult, delta_mult\[, energy_mult\]\) of shape \(\.\.\., 2\) or \(\.\.\., 3\) "
            r"\(got shape \(1,\)\)"),
    (2.0, r"^p: must be .* \(got shape \(\)\)"),
    ([1.0, 1.0, 1.0, 1.0], r"^p: must be .* \(got shape \(4,\)\)"),
])
def test_step_and_simulate_refuse_multipliers_that_are_not_finite_positive_pairs(model, p, needle):
    """NaN, inf and negative factors ran (NaN or meaningless states); p=[1] and p=2.0 were IndexErrors."""
    with pytest.raises(InputError, match=needle):
        model.step(model.x0(), U, 0.5, p)
    with pytest.raises(InputError, match=needle):
        model.simulate(model.x0(), [U], 0.5, p)


def test_step_names_the_bad_row_of_a_batch_of_multipliers(model):
    X = np.tile(model.x0(), (4, 1))
    P = np.ones((4, 2))
    P[2, 1] = math.nan
    with pytest.raises(InputError, match=r"^p\[2\]: delta_mult must be a finite number >= 0 \(got nan\)"):
        model.step(X, U, 0.5, P)


# --- states ------------------------------------------------------------------------------------
@pytest.mark.parametrize("i, v, needle", [
    (0, math.nan, r"s_mean_um must be finite \(got nan\)"),
    (4, math.inf, r"temperature_c must be finite \(got inf\)"),
    (5, math.nan, r"hardening must be finite \(got nan\)"),
    (5, 1.5, r"hardening must be in \[0, 1\] \(got 1\.5\)"),
    (5, -0.1, r"hardening must be in \[0, 1\] \(got -0\.1\)"),
    (4, -300.0, r"temperature_c must be >= -273\.15 °C \(absolute zero\) \(got -300\)"),
])
def test_step_and_simulate_refuse_impossible_states(model, i, v, needle):
    """A NaN state, a hardening outside [0, 1] or a temperature below absolute zero ran silently."""
    x = _x(model, i, v)
    with pytest.raises(InputError, match="^x: " + needle):
        model.step(x, U, 0.5)
    with pytest.raises(InputError, match="^x0: " + needle):
        model.simulate(x, [U], 0.5)


def test_step_names_the_bad_row_of_a_batch_of_states(model):
    X = np.tile(model.x0(), (5, 1))
    X[3, 5] = 2.0
    with pytest.raises(InputError, match=r"^x\[3\]: hardening must be in \[0, 1\] \(got 2\)"):
        model.step(X, U, 0.5, np.ones((5, 2)))


def test_states_and_multipliers_at_their_limits_still_run(model):
    for x in (_x(model, 5, 0.0), _x(model, 5, 1.0), _x(model, 4, -273.15)):
        assert np.all(np.isfinite(model.step(x, U, 0.5)))
    assert np.all(np.isfinite(model.step(model.x0(), U, 0.5, (0.0, 0.0))))
    assert np.all(np.isfinite(model.simulate(model.x0(), [U, U], 0.5, (1.2, 0.8, 1.1))))


# --- linearize ---------------------------------------------------------------------------------
@pytest.mark.parametrize("x, u, p, needle", [
    (None, [5000.0, 1.0], None, r"^u: rpm must be a number in \[0, 600\]"),
    (None, [-300.0, 1.0], None, r"^u: rpm must be a number in \[0, 600\]"),
    (None, [300.0, 5.0], None, r"^u: milling must be a number in \[0, 1\]"),
    (None, [300.0], None, r"^u: must be one \(rpm, milling\) of shape \(2,\) \(got shape \(1,\)\)"),
    (None, [math.nan, 1.0], None, r"^u: rpm must be a number"),
    ("short", U, None, r"^x: must be one state .* of shape \(6,\) \(got shape \(5,\)\)"),
    ("nan", U, None, r"^x: s_mean_um must be finite \(got nan\)"),
    (None, U, (math.nan, 1.0), r"^p: gamma_mult must be a finite number >= 0"),
    (None, U, (1.0, 1.0, 1.0), r"^p: must be \(gamma_mult, delta_mult\) of shape \(2,\)"),
])
@pytest.mark.parametrize("dt_h", [None, 0.5])
def test_linearize_refuses_what_step_refuses(model, x, u, p, needle, dt_h):
    """rpm 5000, -300, milling 5 and NaN x linearised silently; u=[300] was broadcast to (300, 300) by casadi;
    a short x was a raw casadi RuntimeError."""
    x = {None: model.x0(), "short": model.x0()[:5], "nan": _x(model, 0, math.nan)}[x]
    with pytest.raises(InputError, match=needle):
        model.linearize(x, u, p, dt_h)


def test_linearize_of_a_valid_point_is_unchanged(model):
    from bmctl.moments.linear import jacobians

    x = model.step(model.x0(), U, 1.0)
    sys_ = model.linearize(x, U)
    A, B = jacobians(model, list(x), tuple(U), [1.0, 1.0])
    assert np.array_equal(sys_.A, A) and np.array_equal(sys_.B, B) and np.all(np.isfinite(A))


# --- loglik ------------------------------------------------------------------------------------
@pytest.mark.parametrize("s, r, needle", [
    ([0.0, 10.0], [0.1, 0.1], r"^loglik: particle 1: s_um must be > 0 \(got 0\)"),
    ([10.0, -1.0], [0.1, 0.1], r"^loglik: particle 2: s_um must be > 0 \(got -1\)"),
    ([10.0, 10.0], [1.0, 0.1], r"^loglik: particle 1: r must be in \[0, 1\) \(got 1\)"),
    ([10.0, 10.0], [0.1, -0.1], r"^loglik: particle 2: r must be in \[0, 1\) \(got -0\.1\)"),
    ([], [], r"^loglik: s_um, r: a sample needs one or more measured particles"),
])
def test_loglik_refuses_impossible_or_empty_samples(model, s, r, needle):
    """s <= 0 and r outside [0, 1) were scored; an empty sample returned 0.0."""
    with pytest.raises(InputError, match=needle):
        model.loglik(model.x0(), s, r)
