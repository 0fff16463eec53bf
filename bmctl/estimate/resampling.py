"""Resampling schemes with one signature, driven by the run's Generator.

Every scheme is ``resample(weights, rng) -> indices`` (int array of ``len(weights)``), in the
style of ``particles.resampling`` (Chopin): all uniforms come from the caller's
``numpy.random.Generator``; numpy's global random state is never read or written, so two
filters in one process keep independent, reproducible streams.

Schemes (Douc, Cappe & Moulines 2005; Hol, Schon & Gustafsson 2006), with N the number of
particles and w the normalised weights:

systematic
    one uniform U; positions (U + i) / N, i = 0..N-1. Counts lie within floor/ceil of N w.
stratified
    one uniform per stratum; positions (U_i + i) / N.
residual
    floor(N w) deterministic copies, the rest multinomial on the residual N w - floor(N w)
    (Liu & Chen 1998).
multinomial
    N independent uniforms, inverted through the cumulative weights.

All four are unbiased: E[count_i] = N w_i.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputError, require_generator


def _weights(weights) -> np.ndarray:
    """``weights`` as a float array, or an :class:`InputError`: one or more, finite, >= 0, not all 0."""
    w = np.asarray(weights, dtype=float)
    if w.ndim != 1 or w.size == 0:
        raise InputError(f"weights: one weight per particle, a 1-D array of one or more (got shape {w.shape})")
    total, lo = float(w.sum()), float(w.min())
    if not (lo >= 0.0 and 0.0 < total < math.inf):  # NaN fails too
        raise InputError(f"weights: must be finite, >= 0 and not all 0 (got min {lo:g}, sum {total:g})")
    return w


def _cumulative(w: np.ndarray) -> np.ndarray:
    c = np.cumsum(w / w.sum())
    c[-1] = 1.0  # no index past the end from round-off
    return c


def _invert(w: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Index j with cum[j-1] <= position < cum[j] for every position in [0, 1)."""
    return np.minimum(np.searchsorted(_cumulative(w), positions, side="right"), w.size - 1).astype(np.int64)


def systematic(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Systematic resampling: one uniform, N evenly spaced positions.

    Parameters
    ----------
    weights : ndarray
        Weights (normalised inside).
    rng : numpy.random.Generator
        Source of the uniform.

    Returns
    -------
    ndarray of int
    """
    w = _weights(weights)
    require_generator(rng, "rng")
    N = w.size
    return _invert(w, (rng.random() + np.arange(N)) / N)


def stratified(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Stratified resampling: one uniform in each of N equal strata of [0, 1).

    Parameters
    ----------
    weights : ndarray
        Weights (normalised inside).
    rng : numpy.random.Generator
        Source of the uniforms.

    Returns
    -------
    ndarray of int
    """
    w = _weights(weights)
    require_generator(rng, "rng")
    N = w.size
    return _invert(w, (rng.random(N) + np.arange(N)) / N)


def multinomial(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Multinomial resampling: N independent draws from the weights.

    Parameters
    ----------
    weights : ndarray
        Weights (normalised inside).
    rng : numpy.random.Generator
        Source of the uniforms.

    Returns
    -------
    ndarray of int
    """
    w = _weights(weights)
    require_generator(rng, "rng")
    return _invert(w, rng.random(w.size))


def residual(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Residual resampling: floor(N w) copies, the rest multinomial on the residual.

    Parameters
    ----------
    weights : ndarray
        Weights (normalised inside).
    rng : numpy.random.Generator
        Source of the uniforms of the residual draw.

    Returns
    -------
    ndarray of int
    """
    w = _weights(weights)
    require_generator(rng, "rng")
    w = w / w.sum()
    N = w.size
    copies = np.floor(N * w).astype(np.int64)
    idx = np.repeat(np.arange(N, dtype=np.int64), copies)
    k = idx.size
    if k >= N:
        return idx[:N]
    rest = N * w - copies
    return np.concatenate([idx, _invert(rest, rng.random(N - k))])


_SCHEMES = {"systematic": systematic, "stratified": stratified, "residual": residual, "multinomial": multinomial}
SCHEMES = tuple(_SCHEMES)


def resample(weights: np.ndarray, rng: np.random.Generator, scheme: str = "systematic") -> np.ndarray:
    """Indices of the resampled particles.

    Parameters
    ----------
    weights : ndarray
        Normalised weights (sum 1).
    rng : numpy.random.Generator
        The single source of randomness.
    scheme : {"systematic", "stratified", "residual", "multinomial"}
        Resampling scheme.

    Returns
    -------
    ndarray of int

    Raises
    ------
    bmctl.errors.InputError
        No weights, or weights that are not finite, >= 0 and not all 0 (every scheme alike).
    TypeError
        ``rng`` is not a ``numpy.random.Generator``.

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
    return fn(weights, rng)


def effective_sample_size(weights: np.ndarray) -> float:
    """ESS = 1 / sum(w^2) of normalised weights.

    Parameters
    ----------
    weights : ndarray
        Normalised weights (sum 1).

    Raises
    ------
    bmctl.errors.InputError
        No weights, or weights that are not finite, >= 0 and not all 0.
    """
    return float(1.0 / np.sum(np.square(_weights(weights))))
