"""Resampling schemes with one uniform signature, reproducible from a Generator.

filterpy's ``filterpy.monte_carlo`` schemes draw from numpy's *global* random state. Each
wrapper here seeds that state from the caller's ``numpy.random.Generator`` for the duration of
the call and restores it afterwards, so a run's seed fixes its output and no other code's
global stream is disturbed.

Every scheme: ``resample(weights, rng) -> indices`` (int array of len(weights)). The residual
scheme is filterpy's algorithm with a bug fixed (see :func:`_residual_resample`).
"""

from __future__ import annotations

import contextlib

import numpy as np
from filterpy import monte_carlo as mc

def _residual_resample(weights: np.ndarray) -> np.ndarray:
    """Residual resampling (Liu & Chen 1998), filterpy's algorithm with its residual fixed.

    filterpy 1.4.5 ``residual_resample`` takes the residual as ``w - floor(N w)`` instead of
    ``N w - floor(N w)``, which makes the residual draw non-monotone and biased (tests catch
    it: resampled counts no longer follow the weights). Same draws from numpy's global state.
    """
    w = np.asarray(weights, dtype=float)
    N = w.size
    copies = np.floor(N * w).astype(np.int64)
    idx = np.repeat(np.arange(N), copies)
    k = idx.size
    if k >= N:
        return idx[:N]
    residual = N * w - copies
    cumulative_sum = np.cumsum(residual / residual.sum())
    cumulative_sum[-1] = 1.0
    rest = np.searchsorted(cumulative_sum, np.random.random(N - k))
    return np.concatenate([idx, rest])


_SCHEMES = {
    "systematic": mc.systematic_resample,
    "stratified": mc.stratified_resample,
    "residual": _residual_resample,
    "multinomial": mc.multinomial_resample,
}


@contextlib.contextmanager
def _global_state_from(rng: np.random.Generator):
    saved = np.random.get_state()
    np.random.seed(int(rng.integers(0, 2**32 - 1)))
    try:
        yield
    finally:
        np.random.set_state(saved)


def resample(weights: np.ndarray, rng: np.random.Generator, scheme: str = "systematic") -> np.ndarray:
    """Indices of the resampled particles.

    Parameters
    ----------
    weights : ndarray
        Normalised weights (sum 1).
    rng : numpy.random.Generator
        The single source of randomness.
    scheme : {"systematic", "stratified", "residual", "multinomial"}
        filterpy scheme.

    Returns
    -------
    ndarray of int

    Examples
    --------
    >>> import numpy as np
    >>> idx = resample(np.array([0.0, 1.0, 0.0]), np.random.default_rng(0))
    >>> idx.tolist()
    [1, 1, 1]
    """
    try:
        fn = _SCHEMES[scheme]
    except KeyError:
        raise ValueError(f"unknown resampling scheme {scheme!r}; choose from {sorted(_SCHEMES)}") from None
    w = np.asarray(weights, dtype=float)
    with _global_state_from(rng):
        idx = np.asarray(fn(w), dtype=np.int64)
    return np.minimum(idx, w.size - 1)


def effective_sample_size(weights: np.ndarray) -> float:
    """ESS = 1 / sum(w^2) of normalised weights.

    Parameters
    ----------
    weights : ndarray
        Normalised weights (sum 1).
    """
    return float(1.0 / np.sum(np.square(weights)))


SCHEMES = tuple(_SCHEMES)
