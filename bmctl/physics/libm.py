"""Element-wise exp, log1p, cbrt and pow through the C library (Python's ``math``), for the plant's
numpy engine.

numpy's own float64 ``exp``, ``log1p``, ``cbrt`` and ``power`` use SIMD code on CPUs with AVX-512 that
differs from the C library in the last bit; the compiled (numba) engine calls the C library. The
numpy engine calls these instead, so the two engines give the same bits on every CPU and a run's
output does not depend on whether the compiled code was in the cache (docs/performance.md). They
cost 17-55 ns an element (numpy's: about 1 ns), on the arrays of the particles an impact round
changes.

Examples
--------
>>> import math
>>> import numpy as np
>>> x = np.array([-0.5, -3.0])
>>> bool(np.all(exp(x) == [math.exp(-0.5), math.exp(-3.0)]))
True
>>> exp(np.zeros((2, 0))).shape
(2, 0)
"""

from __future__ import annotations

import functools
import math

import numpy as np


def _map(fn, x: np.ndarray, *args) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    return np.fromiter((fn(v, *args) for v in x.ravel().tolist()), float, x.size).reshape(x.shape)


def _complex_exp(x: np.ndarray) -> np.ndarray:
    z = np.empty(x.shape, complex)
    z.real, z.imag = x, 0.0
    return np.exp(z).real  # the C library's cexp, which is its exp on the real axis (no SIMD version)


@functools.cache
def _complex_is_exact() -> bool:
    """Whether numpy's complex exp on the real axis gives the C library's exp here (checked once,
    on values across the range the plant uses and beyond)."""
    x = np.concatenate([np.linspace(-745.0, 709.0, 4001), np.random.default_rng(0).uniform(-60.0, 60.0, 4000),
                        [0.0, -0.0, 1e-300, -1e-300]])
    return bool(np.array_equal(_complex_exp(x), _map(math.exp, x)))


def exp(x) -> np.ndarray:
    """e**x element-wise, the C library's ``exp`` (through numpy's complex exp where that is checked
    to give the same bits, about 17 ns an element; else element by element, about 55 ns).

    Parameters
    ----------
    x : array_like
    """
    x = np.asarray(x, dtype=float)
    return _complex_exp(x) if _complex_is_exact() else _map(math.exp, x)


def log1p(x) -> np.ndarray:
    """ln(1 + x) element-wise, the C library's ``log1p``.

    Parameters
    ----------
    x : array_like
    """
    return _map(math.log1p, x)


def cbrt(x) -> np.ndarray:
    """The real cube root element-wise, the C library's ``cbrt``.

    Parameters
    ----------
    x : array_like
    """
    return _map(math.cbrt, x)


def power(x, p: float) -> np.ndarray:
    """x**p element-wise for one exponent ``p``, the C library's ``pow``.

    Parameters
    ----------
    x : array_like
    p : float
    """
    return _map(math.pow, x, float(p))
