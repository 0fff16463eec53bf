"""Likelihood of a micrograph sample under the distributions a moment state implies.

Size: log-normal with the state's mean and std of s (um); aspect ratio: Beta on (0, 1) with
the state's mean and std of r. Measurement noise: multiplicative on s (log-normal, std
``sigma_log_s``) and additive on r (std ``sigma_r``); both widen the laws in closed form:

    log s_meas ~ N(mu, sigma^2 + sigma_log_s^2)
    r_meas ~ Beta with mean m_r and variance v_r + sigma_r^2 (moment-matched, kept feasible)

Measured r is clipped to [R_FLOOR, 1 - R_FLOOR] (half of the paper's 0.01 raster) so that a
measured circle (r = 0) has finite likelihood.

The functions work on sufficient statistics, so a particle filter with N state particles and
n measured particles costs O(N + n), not O(N n).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import gammaln

R_FLOOR = 0.005
BETA_VAR_MARGIN = 0.98  # keep v < 0.98 m (1 - m) so that Beta a, b > 0


@dataclass(frozen=True)
class SampleStats:
    """Sufficient statistics of a measured sample (s in um, r dimensionless)."""

    n: int
    sum_log_s: float
    sum_log_s2: float
    sum_log_r: float
    sum_log_1mr: float

    @classmethod
    def from_particles(cls, s_um, r) -> "SampleStats":
        """Statistics of measured particles; s must be > 0 and r in [0, 1)."""
        s_um = np.asarray(s_um, dtype=float)
        r = np.clip(np.asarray(r, dtype=float), R_FLOOR, 1 - R_FLOOR)
        ls = np.log(s_um)
        return cls(int(s_um.size), float(ls.sum()), float((ls**2).sum()), float(np.log(r).sum()),
                   float(np.log1p(-r).sum()))


def lognormal_params(mean, std):
    """mu, sigma of the log-normal with the given mean and std (broadcasts)."""
    mean = np.asarray(mean, dtype=float)
    var_ratio = np.square(np.asarray(std, dtype=float) / mean)
    s2 = np.log1p(var_ratio)
    return np.log(mean) - 0.5 * s2, np.sqrt(s2)


def beta_params(mean, std):
    """a, b of the Beta law with the given mean and std; the variance is capped to stay feasible."""
    m = np.clip(np.asarray(mean, dtype=float), 1e-4, 1 - 1e-4)
    v = np.minimum(np.square(np.asarray(std, dtype=float)), BETA_VAR_MARGIN * m * (1 - m))
    v = np.maximum(v, 1e-10)
    k = m * (1 - m) / v - 1.0
    return m * k, (1 - m) * k


def loglik_size(stats: SampleStats, s_mean_um, s_std_um, sigma_log_s: float = 0.0):
    """Log-likelihood of the sizes under a log-normal (vectorised over state particles)."""
    mu, sig = lognormal_params(s_mean_um, s_std_um)
    var = sig**2 + sigma_log_s**2
    n = stats.n
    quad = stats.sum_log_s2 - 2 * mu * stats.sum_log_s + n * mu**2
    return -stats.sum_log_s - 0.5 * n * np.log(2 * np.pi * var) - 0.5 * quad / var


def loglik_aspect(stats: SampleStats, r_mean, r_std, sigma_r: float = 0.0):
    """Log-likelihood of the aspect ratios under a Beta law (vectorised over state particles)."""
    r_std = np.sqrt(np.square(np.asarray(r_std, dtype=float)) + sigma_r**2)
    a, b = beta_params(r_mean, r_std)
    log_beta = gammaln(a) + gammaln(b) - gammaln(a + b)
    return (a - 1) * stats.sum_log_r + (b - 1) * stats.sum_log_1mr - stats.n * log_beta


def loglik_sample(stats: SampleStats, s_mean_um, s_std_um, r_mean, r_std, sigma_log_s: float = 0.05,
                  sigma_r: float = 0.01):
    """Joint log-likelihood of a sample (size and shape independent given the state)."""
    return loglik_size(stats, s_mean_um, s_std_um, sigma_log_s) + loglik_aspect(stats, r_mean, r_std, sigma_r)
