"""Weighted size statistics: number-, area- and volume-weighted quantiles, means and modes.

A powder's size distribution can be counted three ways. A micrograph counts particles
(number weight, power 0); the area fraction of a micrograph weights each particle by its
projected area (power 2); laser diffraction and sieving report mass, i.e. volume (power 3).
The D-values industry quotes (D10, D50, D90 and the span (D90 - D10) / D50) are
*volume-weighted* by the laser-diffraction convention (ISO 13320; often written Dv10 ...).

Two families of pure functions live here, shared by the plant, the moment model and the
particle filter (this module imports neither):

* sample statistics: :func:`weighted_quantile`, :func:`dvalues`, :func:`weighted_mean`,
  :func:`weighted_mode`, :func:`size_stats` (numpy, from a sample of sizes);
* closed forms of a log-normal size law fitted from its number-weighted mean and std
  (:func:`lognormal_params`, :func:`lognormal_weighted_quantile`, :func:`lognormal_size_stats`).
  They accept numpy arrays or casadi symbols (SX/MX/DM), so an MPC can put a D50 target
  into its cost. If ln s ~ N(mu, sigma^2) by number, the s^k-weighted law is again
  log-normal, ln s ~ N(mu + k sigma^2, sigma^2) (Hatch-Choate), so the volume-weighted
  q-quantile is exp(mu + 3 sigma^2 + z_q sigma).

Units: sizes in whatever unit goes in come out (the package passes micrometres, ``*_um``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

WEIGHT_POWER = {"number": 0, "area": 2, "volume": 3}
DVALUE_QUANTILES = {"d10_um": 0.10, "d50_um": 0.50, "d90_um": 0.90}
#: keys of :func:`size_stats` and :func:`lognormal_size_stats` (columns of moments.csv)
SIZE_STAT_NAMES = ("d10_um", "d50_um", "d90_um", "span", "s_mean_area_um", "s_mode_area_um")
MODE_STEP_UM = 1.0  # bin of the mode's histogram (the paper's 1-um raster)
MODE_SMOOTH_BINS = 2.0  # Gaussian smoothing (in bins) before taking the mode


# --- sample statistics -------------------------------------------------------------------------
def weighted_quantile(x: np.ndarray, q, weights: np.ndarray | None = None) -> np.ndarray:
    """Quantiles of a weighted sample (midpoint rule on the weighted empirical CDF).

    Parameters
    ----------
    x : ndarray, (n,)
        Sample values.
    q : float or array_like
        Probabilities in [0, 1].
    weights : ndarray, (n,), optional
        Non-negative weights (default: equal).

    Returns
    -------
    ndarray
        The quantiles, shaped like ``q``. The sorted value k sits at cumulative weight
        (W_k - w_k / 2) / W; between those points the quantile is linearly interpolated;
        outside them it is clamped to the smallest / largest value.

    Examples
    --------
    >>> float(weighted_quantile(np.array([1.0, 2.0, 3.0]), 0.5))
    2.0
    """
    x = np.asarray(x, dtype=float).ravel()
    w = np.ones_like(x) if weights is None else np.asarray(weights, dtype=float).ravel()
    if x.size == 0 or w.shape != x.shape:
        raise ValueError("weighted_quantile: need a non-empty sample and one weight per value")
    qa = np.asarray(q, dtype=float)
    if not np.all((qa >= 0) & (qa <= 1)):  # NaN too: interp clamped 1.5 to the largest value
        raise ValueError(f"weighted_quantile: q must be in [0, 1] (got {q!r})")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(w)) and np.all(w >= 0)):  # a NaN sorted last, unseen
        raise ValueError("weighted_quantile: values and weights must be finite, and weights >= 0")
    order = np.argsort(x, kind="stable")
    xs, ws = x[order], w[order]
    total = ws.sum()
    if not total > 0:
        raise ValueError("weighted_quantile: the weights sum to zero")
    c = (np.cumsum(ws) - 0.5 * ws) / total
    return np.interp(qa, c, xs)


def weighted_mean(s: np.ndarray, power: int) -> float:
    """Mean size under the weight s**power: sum s^(p+1) / sum s^p (power 2: Sauter mean D[3,2]).

    Parameters
    ----------
    s : ndarray
        Sizes (any unit; the result has the same).
    power : int
        0 number, 2 area, 3 volume.
    """
    s = np.asarray(s, dtype=float)
    w = s**power
    return float((w * s).sum() / w.sum())


def weighted_mode(s: np.ndarray, power: int, step: float = MODE_STEP_UM, smooth_bins: float = MODE_SMOOTH_BINS,
                  s_cap: float = 1e4) -> float:
    """Mode of the s**power-weighted density per unit s (linear bins of ``step``, Gaussian-smoothed).

    Power 0 is the number-weighted mode of :func:`bmctl.plant.population.moments` (same bins,
    same smoothing); power 2 the area-weighted mode, the size at which a micrograph's area
    fraction peaks. Returns the centre of the highest smoothed bin.

    Parameters
    ----------
    s : ndarray
        Sizes (um with the default bins).
    power : int
        0 number, 2 area, 3 volume.
    step : float
        Bin width.
    smooth_bins : float
        Gaussian smoothing of the histogram, in bins.
    s_cap : float
        Largest size binned (beyond it, the last bin).
    """
    s = np.asarray(s, dtype=float)
    hi = float(np.clip(s.max() + 1.0, 2.0, s_cap))
    n = int(np.ceil(hi / step))
    idx = np.clip((s / step).astype(np.int64), 0, n - 1)
    h = np.bincount(idx, weights=None if power == 0 else s**power, minlength=n).astype(float)
    h = gaussian_smooth(h, smooth_bins)
    return (np.argmax(h) + 0.5) * step


def gaussian_smooth(h: np.ndarray, sigma_bins: float) -> np.ndarray:
    """``scipy.ndimage.gaussian_filter1d(h, sigma_bins, mode="constant")`` in numpy (no scipy import).

    The same kernel (truncated at 4 sigma, normalised) and zero padding; equal to scipy's to
    round-off (tests/test_stats.py).

    Parameters
    ----------
    h : ndarray, (n,)
        Histogram.
    sigma_bins : float
        Standard deviation of the Gaussian, in bins (> 0).
    """
    radius = int(4.0 * float(sigma_bins) + 0.5)
    x = np.arange(-radius, radius + 1, dtype=float)
    k = np.exp(-0.5 / float(sigma_bins) ** 2 * x * x)
    k /= k.sum()
    return np.convolve(np.asarray(h, dtype=float), k, mode="full")[radius:radius + len(h)]


def dvalues(s: np.ndarray, power: int = 3) -> dict[str, float]:
    """D10, D50, D90 and span = (D90 - D10) / D50 of a sample under the weight s**power (default volume).

    Parameters
    ----------
    s : ndarray
        Sizes; keys ``d10_um, d50_um, d90_um, span`` (the ``_um`` holds when ``s`` is in micrometres).
    power : int
        Weight exponent (3: volume, the laser-diffraction convention).
    """
    s = np.asarray(s, dtype=float)
    d = weighted_quantile(s, list(DVALUE_QUANTILES.values()), s**power)
    out = {k: float(v) for k, v in zip(DVALUE_QUANTILES, d)}
    out["span"] = (out["d90_um"] - out["d10_um"]) / out["d50_um"]
    return out


def size_stats(s_um: np.ndarray) -> dict[str, float]:
    """Volume-weighted D-values and span, area-weighted mean and mode of a sample of sizes (um).

    Parameters
    ----------
    s_um : ndarray
        Sizes (um).

    Returns
    -------
    dict
        ``d10_um, d50_um, d90_um, span`` (volume weight s^3) and ``s_mean_area_um``
        (= Sauter mean D[3,2]), ``s_mode_area_um`` (weight s^2): :data:`SIZE_STAT_NAMES`.

    Examples
    --------
    Nine particles of 10 µm and one of 30 µm: by number the median is 10 µm, but the big
    particle holds 27/36 of the volume, so the volume-weighted D50 lies between the two sizes
    (midpoint rule on the weighted CDF), and the Sauter mean is 360/18 = 20 µm:

    >>> import numpy as np
    >>> st = size_stats(np.array([10.0] * 9 + [30.0]))
    >>> round(st["d50_um"], 1), round(st["s_mean_area_um"], 2)
    (23.6, 20.0)
    """
    out = dvalues(s_um, WEIGHT_POWER["volume"])
    out["s_mean_area_um"] = weighted_mean(s_um, WEIGHT_POWER["area"])
    out["s_mode_area_um"] = float(weighted_mode(s_um, WEIGHT_POWER["area"]))
    return out


# --- closed forms of a log-normal law (numpy or casadi) ---------------------------------------
#: ``scipy.special.ndtri`` at the D-value quantiles, to the last bit (tests/test_stats.py checks them):
#: restoring a filter (``campaign advise``) then needs no scipy import (~0.5 s)
_NDTRI = {0.1: -1.2815515655446004, 0.5: 0.0, 0.9: 1.2815515655446004}


def ndtri(q: float) -> float:
    """Standard normal quantile: ``scipy.special.ndtri`` (imported on first use; the D-value
    quantiles 0.1, 0.5, 0.9 from a table of its values)."""
    z = _NDTRI.get(q)
    if z is not None:
        return z
    from scipy.special import ndtri as _ndtri

    return float(_ndtri(q))


def _ops(*args: Any):
    """The module whose exp/log/sqrt apply: casadi if any argument is a casadi object, else numpy."""
    for a in args:
        if type(a).__module__.split(".")[0] == "casadi":
            import casadi

            return casadi
    return np


def _check_mean_std(where: str, mean, std) -> None:
    """Refuse a number mean that is not finite and > 0 or a std that is not finite and >= 0."""
    m, sd = np.asarray(mean, dtype=float), np.asarray(std, dtype=float)
    if not (np.all(np.isfinite(m)) and np.all(np.isfinite(sd)) and np.all(m > 0) and np.all(sd >= 0)):
        raise ValueError(f"{where}: mean must be finite and > 0, std finite and >= 0 (got mean {mean!r}, std {std!r})")


def lognormal_params(mean, std):
    """(mu, sigma) of the log-normal with number-weighted mean and std (same unit as s).

    sigma^2 = ln(1 + (std/mean)^2), mu = ln(mean) - sigma^2 / 2.

    Parameters
    ----------
    mean, std : array_like or casadi symbol
        Number-weighted mean and standard deviation (> 0).
    """
    xp = _ops(mean, std)
    if xp is np:
        _check_mean_std("lognormal_params", mean, std)
    var_ln = xp.log(1 + (std / mean) ** 2)
    return xp.log(mean) - 0.5 * var_ln, xp.sqrt(var_ln)


def lognormal_weighted_quantile(mu, sigma, q: float, power: int = 3):
    """q-quantile of the s**power-weighted law of a log-normal: exp(mu + power sigma^2 + z_q sigma).

    Parameters
    ----------
    mu, sigma : array_like or casadi symbol
        Log-mean and log-std of the number-weighted law.
    q : float
        Probability in (0, 1).
    power : int
        0 number, 2 area, 3 volume (Hatch-Choate shift of mu by power * sigma^2).
    """
    if not 0.0 < q < 1.0:
        raise ValueError(f"q must be in (0, 1) (got {q})")
    xp = _ops(mu, sigma)
    return xp.exp(mu + power * sigma**2 + float(ndtri(q)) * sigma)


def lognormal_size_stats(mean, std) -> dict:
    """Closed-form :data:`SIZE_STAT_NAMES` of the log-normal fitted from number mean and std.

    d10/d50/d90 are volume-weighted quantiles exp(mu + 3 sigma^2 + z_q sigma); span =
    exp(z_0.9 sigma) - exp(z_0.1 sigma) (independent of mu); the area-weighted mean is
    exp(mu + 2.5 sigma^2) (Sauter mean) and the area-weighted mode (density per unit s)
    exp(mu + sigma^2). Works elementwise on numpy arrays and on casadi symbols.

    Parameters
    ----------
    mean, std : array_like or casadi symbol
        Number-weighted mean and standard deviation of the size (um for ``*_um`` keys).

    Examples
    --------
    >>> st = lognormal_size_stats(40.0, 1e-9)  # a very narrow law: every D-value is the mean
    >>> round(float(st["d50_um"]), 6), round(float(st["span"]), 6)
    (40.0, 0.0)
    """
    mu, sigma = lognormal_params(mean, std)
    xp = _ops(mu, sigma)
    out = {k: lognormal_weighted_quantile(mu, sigma, q, WEIGHT_POWER["volume"]) for k, q in DVALUE_QUANTILES.items()}
    out["span"] = xp.exp(float(ndtri(0.9)) * sigma) - xp.exp(float(ndtri(0.1)) * sigma)
    out["s_mean_area_um"] = xp.exp(mu + 2.5 * sigma**2)
    out["s_mode_area_um"] = xp.exp(mu + sigma**2)
    return out


# --- closed forms of a Weibull law (numpy or casadi) -------------------------------------------
#: Abramowitz & Stegun 6.1.35: Gamma(1 + x) on [0, 1], |error| <= 3e-7
_GAMMA1P = (-0.577191652, 0.988205891, -0.897056937, 0.918206857, -0.756704078, 0.482199394, -0.193527818,
            0.035868343)
WEIBULL_K_MIN = 1.0  # shape floor: cv <= 1 (the plant's cv stays below 0.7)


def _where(xp, cond, a, b):
    return xp.if_else(cond, a, b) if xp is not np else np.where(cond, a, b)


def _gamma1p(y, xp):
    """Gamma(1 + y) for y in [0, 3] (polynomial on [0, 1], then Gamma(1 + y) = y Gamma(y))."""
    def poly(x):
        acc = 0.0
        for b in reversed(_GAMMA1P):
            acc = (acc + b) * x
        return 1.0 + acc

    return _where(xp, y <= 1, poly(y), _where(xp, y <= 2, y * poly(y - 1), y * (y - 1) * poly(y - 2)))


def weibull_params(mean, std):
    """(k, lambda) of the Weibull law with number-weighted mean and std, in closed form.

    k = max(cv^-1.086, 1) (Justus et al. 1978, J. Appl. Meteor. 17, 350), lambda = mean / Gamma(1 + 1/k).
    Numpy arrays or casadi symbols.

    Parameters
    ----------
    mean, std : array_like or casadi symbol
        Number-weighted mean and standard deviation (> 0).
    """
    xp = _ops(mean, std)
    if xp is np:  # a size law of a negative mean gave complex D-values
        _check_mean_std("weibull_params", mean, std)
    k = (std / mean) ** -1.086
    k = xp.fmax(k, WEIBULL_K_MIN) if xp is not np else np.maximum(k, WEIBULL_K_MIN)
    return k, mean / _gamma1p(1.0 / k, xp)


def weibull_size_stats(mean, std) -> dict:
    """Closed-form :data:`SIZE_STAT_NAMES` of the Weibull law fitted from number mean and std.

    With u = (s/lambda)^k, s^3 f(s) ds is proportional to u^(3/k) e^(-u) du: the volume-weighted
    law of u is Gamma(a = 1 + 3/k), so Dq = lambda x_q^(1/k) with x_q its q-quantile, here by the
    Wilson-Hilferty cube x_q = a (1 - 1/(9a) + z_q / (3 sqrt a))^3. Area-weighted mean
    lambda Gamma(1 + 3/k) / Gamma(1 + 2/k); area-weighted mode (density per unit s)
    lambda ((k + 1)/k)^(1/k). Against the exact law (incomplete-gamma inverse, numerical k) the
    D-values are within 2.2 % for cv <= 1 (tests/test_stats.py). Numpy arrays or casadi symbols.

    Parameters
    ----------
    mean, std : array_like or casadi symbol
        Number-weighted mean and standard deviation of the size (um for ``*_um`` keys).
    """
    k, lam = weibull_params(mean, std)
    xp = _ops(k, lam)
    a = 1.0 + 3.0 / k
    out = {}
    for key, q in DVALUE_QUANTILES.items():
        x = a * (1.0 - 1.0 / (9.0 * a) + float(ndtri(q)) / (3.0 * xp.sqrt(a))) ** 3
        out[key] = lam * x ** (1.0 / k)
    out["span"] = (out["d90_um"] - out["d10_um"]) / out["d50_um"]
    out["s_mean_area_um"] = lam * _gamma1p(3.0 / k, xp) / _gamma1p(2.0 / k, xp)
    out["s_mode_area_um"] = lam * ((k + 1.0) / k) ** (1.0 / k)
    return out


#: the law bmctl reads D-values from in the moment model and the particle filter (docs/fidelity.md: on
#: held-out schedules, through the moment model, D50 NRMSE 6-10 % against the log-normal's 15-24 %,
#: D90 8-13 % against 36-67 %)
DVALUE_LAW = "weibull"
law_size_stats = weibull_size_stats


__all__ = ["weibull_params", "weibull_size_stats", "law_size_stats", "DVALUE_LAW", "weighted_quantile", "weighted_mean", "weighted_mode", "dvalues", "size_stats", "lognormal_params",
           "lognormal_weighted_quantile", "lognormal_size_stats", "SIZE_STAT_NAMES", "WEIGHT_POWER",
           "DVALUE_QUANTILES"]
