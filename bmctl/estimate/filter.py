"""A bootstrap particle filter over the moment-model state and uncertain rate parameters.

The model is one small object (the moment model: ``step``, ``x0``, ``p0``, ``state_names``);
the algorithm lives here, apart (as in Chopin's ``particles``). Each particle carries the
moment state x (s_mean_um, s_std_um, r_mean, r_std, temperature_c, hardening) and the log of
the parameter multipliers (bond_mult, frac_mult). Propagation: the moment model under the
applied (rpm, milling) with multiplicative process noise. Update: likelihood of a micrograph
sample (``likelihood.loglik_sample``) and optionally a vial-temperature reading. Resampling
when ESS < ``ess_fraction`` N (filterpy schemes, seeded), then roughening of the parameters
(Gordon, Salmond & Smith 1993) so they do not collapse onto a few values.

Multi-rate by construction: call ``predict`` every control interval and ``update`` only when
a sample (or reading) arrives.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .likelihood import SampleStats, loglik_sample
from .resampling import SCHEMES, effective_sample_size, resample


@dataclass
class FilterSettings:
    """Particle-filter settings (all dimensionless unless suffixed).

    Attributes
    ----------
    n_particles : int
        Number of filter particles N.
    ess_fraction : float
        Resample when ESS < ess_fraction * N.
    scheme : str
        Resampling scheme (filterpy): systematic, stratified, residual, multinomial.
    process_noise_per_sqrt_h : float
        Relative (log-space) random walk of s_mean, s_std, r_mean, r_std per sqrt(hour).
    temperature_noise_c_per_sqrt_h : float
        Additive random walk of the vial temperature (degC per sqrt(hour)).
    param_prior_log_std : float
        Std of the initial log multipliers (0.3 ~ +-30 %).
    param_walk_per_sqrt_h : float
        Random walk of the log multipliers per sqrt(hour).
    roughening : float
        Roughening constant K of Gordon et al. (jitter std = K * range * N^(-1/d)).
    initial_spread : float
        Relative spread of the initial moment states.
    sigma_log_s : float
        Measurement noise on log s (segmentation, 2D sections).
    sigma_r : float
        Measurement noise on r.
    sigma_temperature_c : float
        Noise of a vial-temperature reading.
    """

    n_particles: int = 2000
    ess_fraction: float = 0.5
    scheme: str = "systematic"
    process_noise_per_sqrt_h: float = 0.03
    temperature_noise_c_per_sqrt_h: float = 1.0
    param_prior_log_std: float = 0.35
    param_walk_per_sqrt_h: float = 0.01
    roughening: float = 0.05
    initial_spread: float = 0.02
    sigma_log_s: float = 0.05
    sigma_r: float = 0.01
    sigma_temperature_c: float = 2.0

    def __post_init__(self):
        if self.n_particles < 10:
            raise ValueError("n_particles must be >= 10")
        if not 0 < self.ess_fraction <= 1:
            raise ValueError("ess_fraction must be in (0, 1]")
        if self.scheme not in SCHEMES:
            raise ValueError(f"scheme must be one of {SCHEMES}")


@dataclass
class Estimate:
    """Weighted summary of the filter at one time."""

    t_h: float
    names: tuple[str, ...]
    mean: np.ndarray
    q05: np.ndarray
    q95: np.ndarray
    ess: float
    resampled: bool = False
    degenerate: bool = False

    def as_dict(self) -> dict[str, float]:
        """Flat dict: t_h, ess, and <name>, <name>_q05, <name>_q95 for every state and parameter."""
        d = {"t_h": self.t_h, "ess": self.ess}
        for k, n in enumerate(self.names):
            d[n] = float(self.mean[k])
            d[f"{n}_q05"] = float(self.q05[k])
            d[f"{n}_q95"] = float(self.q95[k])
        return d


def weighted_quantiles(values: np.ndarray, weights: np.ndarray, qs=(0.05, 0.95)) -> np.ndarray:
    """Quantiles of each column of ``values`` (N, d) under ``weights`` (N,). Returns (len(qs), d)."""
    order = np.argsort(values, axis=0)
    out = np.empty((len(qs), values.shape[1]))
    for j in range(values.shape[1]):
        v = values[order[:, j], j]
        c = np.cumsum(weights[order[:, j]])
        c /= c[-1]
        out[:, j] = np.interp(qs, c - 0.5 * weights[order[:, j]] / weights.sum(), v)
    return out


class ParticleFilter:
    """Bootstrap particle filter on a moment model.

    Parameters
    ----------
    model : MomentModel
        Needs ``x0()``, ``p0()``, ``state_names``, ``param_names`` (optional) and a vectorised
        ``step(X, u, dt_h, P)`` for X of shape (N, nx) and P of shape (N, np).
    rng : numpy.random.Generator
        The single source of randomness (resampling included).
    settings : FilterSettings, optional
    x0 : array, optional
        Initial moment state (default ``model.x0()``).

    Examples
    --------
    >>> pf = ParticleFilter(model, np.random.default_rng(0))  # doctest: +SKIP
    >>> pf.predict((300.0, 1.0), 1.0)  # doctest: +SKIP
    >>> est = pf.update(s_um, r)  # doctest: +SKIP
    """

    def __init__(self, model, rng: np.random.Generator, settings: FilterSettings | None = None, x0=None):
        self.model = model
        self.rng = rng
        self.settings = settings or FilterSettings()
        st = self.settings
        N = st.n_particles
        x0 = np.asarray(model.x0() if x0 is None else x0, dtype=float)
        p0 = np.asarray(model.p0(), dtype=float)
        self.nx, self.np_ = x0.size, p0.size
        X = np.tile(x0, (N, 1))
        X[:, :4] *= np.exp(st.initial_spread * rng.standard_normal((N, 4)))
        self.X = X
        self.logP = np.log(p0)[None, :] + st.param_prior_log_std * rng.standard_normal((N, self.np_))
        self.logw = np.full(N, -np.log(N))
        self.t_h = 0.0
        self.state_names = tuple(model.state_names)
        self.param_names = tuple(getattr(model, "param_names", ("bond_mult", "frac_mult")))
        self.n_resampled = 0
        self.n_degenerate = 0

    # --- filter steps ------------------------------------------------------------------------
    @property
    def weights(self) -> np.ndarray:
        w = np.exp(self.logw - self.logw.max())
        return w / w.sum()

    @property
    def P(self) -> np.ndarray:
        """Parameter multipliers of every particle (N, np)."""
        return np.exp(self.logP)

    def predict(self, u, dt_h: float) -> None:
        """Propagate every particle over ``dt_h`` hours under input ``u = (rpm, milling)``."""
        if dt_h <= 0:
            return
        st, rng = self.settings, self.rng
        X = np.asarray(self.model.step(self.X, np.asarray(u, dtype=float), dt_h, self.P), dtype=float)
        sq = np.sqrt(dt_h)
        X[:, :4] *= np.exp(st.process_noise_per_sqrt_h * sq * rng.standard_normal((X.shape[0], 4)))
        X[:, 4] += st.temperature_noise_c_per_sqrt_h * sq * rng.standard_normal(X.shape[0])
        self.X = self._feasible(X)
        self.logP = self.logP + st.param_walk_per_sqrt_h * sq * rng.standard_normal(self.logP.shape)
        self.t_h += dt_h

    @staticmethod
    def _feasible(X: np.ndarray) -> np.ndarray:
        """Keep moment sets realisable: positive sizes, r in (0, 1), Beta-feasible r variance."""
        X[:, 0] = np.maximum(X[:, 0], 0.1)
        X[:, 1] = np.clip(X[:, 1], 1e-3, 10 * X[:, 0])
        X[:, 2] = np.clip(X[:, 2], 1e-4, 0.99)
        X[:, 3] = np.clip(X[:, 3], 1e-4, 0.99 * np.sqrt(X[:, 2] * (1 - X[:, 2])))
        return X

    def update(self, s_um=None, r=None, temperature_c: float | None = None) -> Estimate:
        """Weight particles by a micrograph sample (and/or a temperature reading); resample if needed."""
        st = self.settings
        ll = np.zeros(self.X.shape[0])
        if s_um is not None:
            stats = SampleStats.from_particles(s_um, r)
            ll += loglik_sample(stats, self.X[:, 0], self.X[:, 1], self.X[:, 2], self.X[:, 3],
                                st.sigma_log_s, st.sigma_r)
        if temperature_c is not None:
            ll += -0.5 * ((temperature_c - self.X[:, 4]) / st.sigma_temperature_c) ** 2
        degenerate = False
        logw = self.logw + ll
        if not np.any(np.isfinite(logw)):
            degenerate = True  # every particle impossible: keep the prior weights, report it
            self.n_degenerate += 1
            logw = self.logw.copy()
        logw = np.where(np.isfinite(logw), logw, -np.inf)
        self.logw = logw - (logw.max() + np.log(np.exp(logw - logw.max()).sum()))
        ess = effective_sample_size(self.weights)
        resampled = False
        if ess < st.ess_fraction * self.X.shape[0]:
            self._resample()
            resampled = True
        est = self.estimate()
        est.ess, est.resampled, est.degenerate = ess, resampled, degenerate
        return est

    def _resample(self) -> None:
        st, rng = self.settings, self.rng
        idx = resample(self.weights, rng, st.scheme)
        self.X = self.X[idx].copy()
        self.logP = self.logP[idx].copy()
        N, d = self.logP.shape
        spread = self.logP.max(axis=0) - self.logP.min(axis=0)
        self.logP += st.roughening * np.maximum(spread, 1e-3) * N ** (-1.0 / d) * rng.standard_normal((N, d))
        self.logw = np.full(N, -np.log(N))
        self.n_resampled += 1

    def estimate(self) -> Estimate:
        """Weighted mean and 90 % interval of every state and parameter."""
        w = self.weights
        V = np.hstack([self.X, self.P])
        q = weighted_quantiles(V, w)
        return Estimate(self.t_h, self.state_names + self.param_names, w @ V, q[0], q[1], effective_sample_size(w))
