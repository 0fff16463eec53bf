"""bmctl.physics.libm gives the C library's bits (Python's math), element by element, on any CPU."""

import math

import numpy as np
import pytest

from bmctl.physics import libm


@pytest.mark.parametrize("complex_route", [True, False])
def test_exp_is_the_c_librarys_to_the_last_bit(monkeypatch, complex_route):
    if complex_route and not libm._complex_is_exact():
        pytest.skip("numpy's complex exp is not the C library's exp here (the element route is used)")
    monkeypatch.setattr(libm, "_complex_is_exact", lambda: complex_route)
    x = np.random.default_rng(5).uniform(-60.0, 60.0, 5000).reshape(50, 100)
    got = libm.exp(x)
    assert got.shape == x.shape
    assert all(g == math.exp(v) for g, v in zip(got.ravel(), x.ravel()))


def test_log1p_cbrt_power_are_the_c_librarys():
    x = np.random.default_rng(6).uniform(1e-6, 0.999, 3000)
    assert all(g == math.log1p(-v) for g, v in zip(libm.log1p(-x), x))
    assert all(g == math.cbrt(v) for g, v in zip(libm.cbrt(x), x))
    assert all(g == math.pow(v, 1 / 2.3) for g, v in zip(libm.power(x, 1 / 2.3), x))
    assert libm.log1p(np.empty(0)).shape == (0,)
