"""Likelihood of a micrograph sample under the laws a moment state implies.

A state gives the number-weighted size and aspect-ratio laws of the powder:

size s (um)
    Weibull with the state's mean and std (``size_law="weibull"``, the default), or
    log-normal with them (``size_law="lognormal"``, the moment model's own closure: its s_std misfits the
    plant's populations by 20-43 %, docs/estimation.md). Measurement noise: multiplicative,
    ``ln s_meas = ln s + e``, ``e ~ N(0, sigma_log_s^2)`` (exact for the log-normal,
    variance-matched for the Weibull).
aspect ratio r
    Beta on (0, 1) with the state's mean and std, measured through additive noise and the
    isoperimetric floor of the measurement path: ``r_meas = max(0, r + e)``,
    ``e ~ N(0, sigma_r^2)``. A measured ``r = 0`` (a perimeter raised to pi s,
    :mod:`bmctl.measure.tables`) is the censored event ``r + e <= 0``.

Size and shape are independent given the state (the moment model's mean-field closure).

Two evaluations:

* :func:`loglik_sample` - continuous densities from sufficient statistics (log-normal and
  Beta, noise widening the variances); O(N + n). A reference, and the form the tests check
  against ``scipy.stats``.
* :func:`loglik_raster` - the likelihood the filter uses: each measured particle is counted
  in a raster cell (``ln s`` in steps of ``ds_log``, r in steps of ``dr`` with r = 0 as its
  own cell, as the paper's 1 um x 0.01 raster) and the sample's likelihood is the product of
  the cell probabilities under the noisy laws, ``sum_cells count * log P(cell | state)``.
  Rastering is what makes the r-noise convolution and the r = 0 atom exact and cheap: the
  cost is O(N * cells), independent of n.

:func:`fit_sample` finds the sample's own maximum (in log-moment coordinates), the observed
information there, and the learning rate of Lyddon, Holmes & Walker (2019) for each block
(size, shape), used by the filter's guided proposal and power likelihood.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np


class _Special:
    """``scipy.special``, imported on first use (a fresh `campaign advise` restores the filter without it)."""

    def __getattr__(self, name):
        from scipy import special as sp

        return getattr(sp, name)


special = _Special()

R_FLOOR = 0.005  # continuous form: measured r clipped to [R_FLOOR, 1 - R_FLOOR]
BETA_VAR_MARGIN = 0.98  # keep v < 0.98 m (1 - m) so that Beta a, b > 0
LOG_P_FLOOR = -700.0  # log-probability of an impossible cell (finite: no NaN weights)
#: physical range of a measured size (um): 1 nm to 10 mm
S_RANGE_UM = (1e-3, 1e4)
SIZE_LAWS = ("weibull", "lognormal")
#: relative misfit of each law's (s_mean, s_std, r_mean, r_std) against the plant's populations:
#: the largest |ln(pseudo-true / true)| of 20,000-particle micrograph samples, 3 factor scenarios
#: x 5 times (``python benchmarks/pf_study.py --laws``, docs/estimation.md), rounded up. The
#: log-normal's s_std is 20-43 % too large (its ln s is symmetric, the plant's is skewed left
#: by fragments); the Weibull is within 3 %. The r part (Beta through the noise model) is
#: the same for both.
LAW_MISFIT = {"weibull": (0.02, 0.04, 0.05, 0.07), "lognormal": (0.04, 0.36, 0.05, 0.07)}
EULER_GAMMA = 0.5772156649015329


# --- moment -> law parameters ---------------------------------------------------------------
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


@lru_cache(maxsize=1)
def _weibull_table():
    """(ln cv increasing, ln k) of the Weibull shape table (built on first use)."""
    k = np.exp(np.linspace(np.log(0.15), np.log(80.0), 2000))
    g1 = special.gammaln(1 + 1 / k)
    cv = np.sqrt(np.expm1(special.gammaln(1 + 2 / k) - 2 * g1))
    return np.log(cv[::-1]), np.log(k[::-1])  # increasing ln cv


def weibull_params(mean, std):
    """Shape k and log-scale ln(lambda) of the Weibull with the given mean and std (broadcasts)."""
    mean = np.asarray(mean, dtype=float)
    lncv = np.log(np.asarray(std, dtype=float) / mean)
    k = np.exp(np.interp(lncv, *_weibull_table()))
    return k, np.log(mean) - special.gammaln(1 + 1 / k)


# --- continuous form (sufficient statistics) -------------------------------------------------
@dataclass(frozen=True)
class SampleStats:
    """Sufficient statistics of a measured sample (s in um, r dimensionless).

    Attributes
    ----------
    n : int
        Measured particles.
    sum_log_s, sum_log_s2 : float
        Sums of ln s and (ln s)^2.
    sum_log_r, sum_log_1mr : float
        Sums of ln r and ln(1 - r), r clipped to [R_FLOOR, 1 - R_FLOOR].
    """

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
    log_beta = special.gammaln(a) + special.gammaln(b) - special.gammaln(a + b)
    return (a - 1) * stats.sum_log_r + (b - 1) * stats.sum_log_1mr - stats.n * log_beta


def loglik_sample(stats: SampleStats, s_mean_um, s_std_um, r_mean, r_std, sigma_log_s: float = 0.05,
                  sigma_r: float = 0.01):
    """Joint continuous log-likelihood (log-normal s, Beta r; independent given the state).

    Parameters
    ----------
    stats : SampleStats
        The measured sample.
    s_mean_um, s_std_um, r_mean, r_std : array_like
        Moments of each state (broadcast).
    sigma_log_s : float, optional
        Size-measurement noise (std of ln s), added to the log-variance.
    sigma_r : float, optional
        r-measurement noise, added to the r variance (moment-matched).

    Returns
    -------
    ndarray
        Log-likelihood per state.
    """
    return loglik_size(stats, s_mean_um, s_std_um, sigma_log_s) + loglik_aspect(stats, r_mean, r_std, sigma_r)


def check_particles(s_um, r, where: str) -> None:
    """Refuse measured particles that are no sample: none, unequal numbers of s and r, a size
    outside :data:`S_RANGE_UM` (NaN included) or r outside [0, 1), naming ``where`` and the particle.

    Parameters
    ----------
    s_um, r : ndarray
        Sizes (um) and aspect ratios, float arrays of one shape.
    where : str
        What the message names first (a file, ``sample at 2 h``, ``s_um, r``).

    Raises
    ------
    bmctl.errors.InputError
    """
    from ..errors import InputError

    if s_um.size == 0 or s_um.shape != r.shape:
        raise InputError(f"{where}: a sample needs one or more particles with one s and one r each")
    lo, hi = float(s_um.min()), float(s_um.max())
    if not (S_RANGE_UM[0] <= lo and hi <= S_RANGE_UM[1]):  # NaN fails too
        k = int(np.argmax(~((s_um >= S_RANGE_UM[0]) & (s_um <= S_RANGE_UM[1]))))
        raise InputError(f"{where}: particle {k + 1}: s_um = {s_um.flat[k]:.4g} outside [{S_RANGE_UM[0]:g}, "
                         f"{S_RANGE_UM[1]:g}] µm")
    lo, hi = float(r.min()), float(r.max())
    if not (0.0 <= lo and hi < 1.0):
        k = int(np.argmax(~((r >= 0) & (r < 1))))
        raise InputError(f"{where}: particle {k + 1}: r = {r.flat[k]:.4g} outside [0, 1)")


# --- rastered form (the filter's likelihood) -------------------------------------------------
@dataclass(frozen=True)
class LawSettings:
    """The measurement laws and their raster.

    Attributes
    ----------
    size_law : {"weibull", "lognormal"}
        Law of s given (s_mean, s_std).
    sigma_log_s : float
        Std of the multiplicative size-measurement noise (ln s). The synthetic micrograph
        path (``bmctl.measure.sampler``, area noise 0.03) gives 0.015.
    sigma_r : float
        Std of the additive r-measurement noise, >= dr / 2. The synthetic path (area and
        perimeter noise 0.03 each) gives sqrt(0.03^2 + 0.015^2) = 0.034.
    ds_log : float
        Raster cell width in ln s (0.05: 5 % steps, well below the population's spread).
    dr : float
        Raster cell width in r (the paper's 0.01).
    misfit : tuple of 4 floats, optional
        Relative error of (s_mean, s_std, r_mean, r_std) that the law itself makes however
        many particles are measured (its shape is not the powder's): a floor under the
        per-sample uncertainty, applied by the filter through the learning rate. Default:
        :data:`LAW_MISFIT` of the size law, from the pseudo-true moments of each law fitted
        to large plant samples (docs/estimation.md).
    """

    size_law: str = "weibull"
    sigma_log_s: float = 0.015
    sigma_r: float = 0.034
    ds_log: float = 0.05
    dr: float = 0.01
    misfit: tuple | None = None

    @property
    def misfit_floor(self) -> np.ndarray:
        """The relative law-misfit std of each log moment (4,)."""
        return np.asarray(LAW_MISFIT[self.size_law] if self.misfit is None else self.misfit, dtype=float)

    def __post_init__(self):
        for name in ("sigma_log_s", "sigma_r", "ds_log", "dr"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"{name} must be a finite number (got {v!r})")
        if self.misfit is not None and not all(isinstance(v, (int, float)) and math.isfinite(v) for v in self.misfit):
            raise ValueError(f"misfit: four finite numbers (got {self.misfit!r})")
        if self.size_law not in SIZE_LAWS:
            raise ValueError(f"size_law must be one of {SIZE_LAWS} (got {self.size_law!r})")
        if not (self.ds_log > 0 and self.dr > 0 and 1 / self.dr == round(1 / self.dr)):
            raise ValueError("ds_log must be > 0 and dr > 0 must divide 1")
        if self.sigma_log_s < 0 or self.sigma_r < self.dr / 2:
            raise ValueError(f"sigma_log_s must be >= 0 and sigma_r >= dr/2 = {self.dr / 2:g}")
        if self.misfit is not None and (len(self.misfit) != 4 or min(self.misfit) < 0):
            raise ValueError("misfit: four values >= 0")


@dataclass(frozen=True)
class Raster:
    """A measured sample counted on the likelihood raster.

    Attributes
    ----------
    n : int
        Measured particles.
    ds_log, dr : float
        Raster cell widths in ln s and in r.
    s_k0 : int
        Index of the first size cell (cell k covers ln s in [k ds, (k+1) ds)).
    s_counts : ndarray
        Counts of the contiguous size cells s_k0, s_k0 + 1, ...
    r_zero : int
        Particles measured with r = 0 exactly.
    r_cells, r_counts : ndarray
        Occupied r cells (cell j covers r in (j dr, (j+1) dr]) and their counts.
    moments : tuple
        The sample's own (s_mean, s_std, r_mean, r_std).
    """

    n: int
    ds_log: float
    dr: float
    s_k0: int
    s_counts: np.ndarray
    r_zero: int
    r_cells: np.ndarray
    r_counts: np.ndarray
    moments: tuple
    _cache: dict = field(default_factory=dict, init=False, compare=False, repr=False)

    @classmethod
    def from_particles(cls, s_um, r, law: LawSettings | None = None) -> "Raster":
        """Count measured particles (s in :data:`S_RANGE_UM` in um, r in [0, 1)) on the raster of ``law``.

        Raises
        ------
        bmctl.errors.InputError
            As :func:`check_particles` (naming ``s_um, r``).
        """
        law = law or LawSettings()
        s_um = np.asarray(s_um, dtype=float).ravel()
        r = np.asarray(r, dtype=float).ravel()
        check_particles(s_um, r, "s_um, r")
        ks = np.floor(np.log(s_um) / law.ds_log).astype(np.int64)
        k0 = int(ks.min())
        s_counts = np.bincount(ks - k0).astype(float)
        zero = r <= 0.0
        nr = int(round(1 / law.dr))
        kr = np.clip(np.ceil(r[~zero] / law.dr).astype(np.int64) - 1, 0, nr - 1)
        rc = np.bincount(kr, minlength=nr).astype(float)
        occ = np.flatnonzero(rc)
        mom = (float(s_um.mean()), float(s_um.std()), float(r.mean()), float(r.std()))
        return cls(int(s_um.size), law.ds_log, law.dr, k0, s_counts, int(zero.sum()), occ, rc[occ], mom)

    def s_edges(self) -> np.ndarray:
        """ln-s edges of the contiguous size cells (len(s_counts) + 1)."""
        return (self.s_k0 + np.arange(self.s_counts.size + 1)) * self.ds_log


def _interval_prob(lo, hi):
    """Phi(hi) - Phi(lo) without cancellation in the upper tail."""
    return np.where(lo > 0, special.ndtr(-lo) - special.ndtr(-hi), special.ndtr(hi) - special.ndtr(lo))


_P_FLOOR = math.exp(LOG_P_FLOOR)


def _safe_log(p):
    """log of probabilities, floored at LOG_P_FLOOR (NaN -> floor too: np.fmax ignores NaN)."""
    return np.log(np.fmax(p, _P_FLOOR))


def size_cell_logp(raster: Raster, s_mean, s_std, law: LawSettings) -> np.ndarray:
    """log P(size cell | state) for every state (rows) and contiguous size cell (columns)."""
    e = raster.s_edges()[None, :]
    s_mean = np.asarray(s_mean, dtype=float)[:, None]
    s_std = np.asarray(s_std, dtype=float)[:, None]
    if law.size_law == "lognormal":
        mu, sig = lognormal_params(s_mean, s_std)
        sig = np.sqrt(sig**2 + law.sigma_log_s**2)
        z = (e - mu) / sig
        t = special.ndtr(-np.abs(z))  # one pass: Phi(z) = t (z < 0), 1 - t (z >= 0); no upper-tail cancellation
        lo, hi, tlo, thi = z[:, :-1], z[:, 1:], t[:, :-1], t[:, 1:]
        p = np.where(lo >= 0, tlo - thi, np.where(hi <= 0, thi - tlo, 1.0 - thi - tlo))
    else:
        k, lnlam = weibull_params(s_mean, s_std)
        beta = 1.0 / k  # ln s is Gumbel-min with scale 1/k; noise widens it (variance-matched)
        beta_n = np.sqrt(beta**2 + 6 * law.sigma_log_s**2 / np.pi**2)
        loc = lnlam - EULER_GAMMA * beta + EULER_GAMMA * beta_n
        ez = np.exp(np.minimum((e - loc) / beta_n, 700.0))  # cumulative hazard at each edge
        p = np.exp(-ez[:, :-1]) * -np.expm1(ez[:, :-1] - ez[:, 1:])
    return _safe_log(p)


def _r_kernel(raster: Raster, law: LawSettings) -> tuple[np.ndarray, np.ndarray]:
    """Noise kernel P(measured cell | true r) at the fine-cell midpoints, atom column first,
    and its derivative in the true r (used to move the near-zero cells to their Beta means)."""
    key = ("K", law.sigma_r)
    if key not in raster._cache:
        dr, sig = raster.dr, law.sigma_r
        nr = int(round(1 / dr))
        mid = (np.arange(nr) + 0.5) * dr
        lo = raster.r_cells * dr
        zlo = (lo[None, :] - mid[:, None]) / sig
        zhi = (lo[None, :] + dr - mid[:, None]) / sig
        K = np.empty((nr, raster.r_cells.size + 1))
        K[:, 0] = special.ndtr(-mid / sig)
        K[:, 1:] = _interval_prob(zlo, zhi)
        k0 = EXACT_R_CELLS
        dK = np.empty((k0, K.shape[1]))
        pdf = lambda z: np.exp(-0.5 * z * z) / math.sqrt(2 * math.pi)  # noqa: E731
        dK[:, 0] = -pdf(mid[:k0] / sig) / sig
        dK[:, 1:] = (pdf(zlo[:k0]) - pdf(zhi[:k0])) / sig
        last = int(min(nr, raster.r_cells.max(initial=0) + 1 + np.ceil(6 * sig / dr)))  # kernel < 1e-9 beyond
        raster._cache[key] = (K[:max(last, k0)], dK)
    return raster._cache[key]


EXACT_R_CELLS = 4  # fine r cells near 0 with exact Beta mass and mean (the density is singular there when a < 1)


@lru_cache(maxsize=8)
def _r_grid(dr: float) -> np.ndarray:
    """Rows ln(mid), ln(1 - mid), 1 over the midpoint cells (3, nr - EXACT_R_CELLS)."""
    mid = (np.arange(EXACT_R_CELLS, int(round(1 / dr))) + 0.5) * dr
    return np.stack([np.log(mid), np.log1p(-mid), np.ones_like(mid)])


def true_r_masses(r_mean, r_std, dr: float, rows: int | None = None, offsets: bool = False):
    """Beta masses of the fine r cells [j dr, (j+1) dr) for every state (N, rows).

    The first ``EXACT_R_CELLS`` cells are exact (regularised incomplete Beta: the density is
    singular at 0 when a < 1); the others are the density at the midpoint, scaled so that
    they hold the rest of the mass. With ``offsets``, also return the Beta mean of each exact
    cell minus its midpoint (N, EXACT_R_CELLS), from E[r; r < x] = a / (a + b) I_x(a + 1, b).
    """
    a, b = beta_params(r_mean, r_std)
    N = a.shape[0]
    nr = int(round(1 / dr))
    k0 = EXACT_R_CELLS
    edges = dr * np.arange(1, k0 + 1)[None, :]
    cdf = special.betainc(a[:, None], b[:, None], edges)
    out = np.empty((N, nr))
    # log density at the midpoints in one pass: [a - 1, b - 1, -ln B(a, b)] @ [ln m; ln(1 - m); 1]
    coef = np.stack([a - 1, b - 1, -special.betaln(a, b)], axis=1)
    d = out[:, k0:]
    np.matmul(coef, _r_grid(dr), out=d)
    np.exp(d, out=d)
    d *= ((1 - cdf[:, -1]) / np.maximum(d.sum(axis=1), 1e-300))[:, None]
    out[:, 0] = cdf[:, 0]
    out[:, 1:k0] = np.diff(cdf, axis=1)
    if rows is not None:
        out = out[:, :rows]
    if not offsets:
        return out
    a2, b2 = a[:, None], b[:, None]
    m1 = (a2 / (a2 + b2)) * special.betainc(a2 + 1, b2, edges)  # E[r; r < edge]
    dm1 = np.diff(m1, axis=1, prepend=0.0)
    mass = out[:, :k0]
    mid = (np.arange(k0) + 0.5) * dr
    cell_mean = np.where(mass > 1e-12, dm1 / np.maximum(mass, 1e-300), mid[None, :])
    return out, np.clip(cell_mean, 0.0, edges) - mid[None, :]


def shape_cell_logp(raster: Raster, r_mean, r_std, law: LawSettings) -> np.ndarray:
    """log P(r cell | state): columns are the r = 0 atom, then the occupied r cells.

    P = sum_j W_j K(mu_j), with W_j the Beta mass of fine cell j and K the noise kernel at the
    cell's location mu_j: the midpoint, or for the exact cells near 0 the Beta mean within the
    cell (K linearised about the midpoint; the shift is < dr, a fraction of sigma_r).
    """
    K, dK = _r_kernel(raster, law)
    W, off = true_r_masses(np.asarray(r_mean, dtype=float), np.asarray(r_std, dtype=float), raster.dr,
                           K.shape[0], offsets=True)
    k0 = EXACT_R_CELLS
    return _safe_log(W @ K + (W[:, :k0] * off) @ dK)


def loglik_raster(raster: Raster, s_mean, s_std, r_mean, r_std, law: LawSettings | None = None):
    """Log-likelihood of a rastered sample under the laws of every state, size and shape apart.

    Parameters
    ----------
    raster : Raster
        The measured sample.
    s_mean, s_std, r_mean, r_std : array_like, (N,)
        Moments of each state.
    law : LawSettings, optional
        Laws, noise and raster (default ``LawSettings()``).

    Returns
    -------
    (ndarray, ndarray)
        Size and shape log-likelihoods, each (N,); their sum is the sample's.
    """
    law = law or LawSettings()
    ls = size_cell_logp(raster, np.atleast_1d(s_mean), np.atleast_1d(s_std), law) @ raster.s_counts
    lr_cells = shape_cell_logp(raster, np.atleast_1d(r_mean), np.atleast_1d(r_std), law)
    lr = lr_cells[:, 0] * raster.r_zero + lr_cells[:, 1:] @ raster.r_counts
    return ls, lr


# --- the sample's own fit -------------------------------------------------------------------
@dataclass
class SampleFit:
    """Maximum of a sample's likelihood in z = ln(s_mean, s_std, r_mean, r_std).

    Attributes
    ----------
    z : ndarray (4,)
        Maximiser.
    info : ndarray (4, 4)
        Observed information (minus the Hessian of the log-likelihood), block diagonal.
    eta : ndarray (2,)
        Learning rates of the size and shape blocks (Lyddon, Holmes & Walker 2019):
        tr(I J^-1 I) / tr(I), I the information, J the sum of squared per-particle scores;
        1 when the law fits, < 1 when the sample is more variable than the law says.
    ok : ndarray of bool (2,)
        Whether each block converged to a proper maximum.
    """

    z: np.ndarray
    info: np.ndarray
    eta: np.ndarray
    ok: np.ndarray


_STENCIL = np.array([[0, 0], [1, 0], [-1, 0], [0, 1], [0, -1], [1, 1], [-1, -1]], dtype=float)


def _block_derivs(cell_logp: np.ndarray, counts: np.ndarray, h: float):
    """Gradient, Hessian of sum(counts * cell_logp) and per-cell scores from the 7-point stencil."""
    f = cell_logp @ counts
    g = np.array([(f[1] - f[2]) / (2 * h), (f[3] - f[4]) / (2 * h)])
    h11 = (f[1] - 2 * f[0] + f[2]) / h**2
    h22 = (f[3] - 2 * f[0] + f[4]) / h**2
    h12 = (f[5] - f[1] - f[3] + 2 * f[0] - f[2] - f[4] + f[6]) / (2 * h**2)
    scores = np.stack([(cell_logp[1] - cell_logp[2]) / (2 * h), (cell_logp[3] - cell_logp[4]) / (2 * h)], axis=1)
    return f[0], g, np.array([[h11, h12], [h12, h22]]), scores


def _z_feasible(z: np.ndarray) -> np.ndarray:
    z = z.copy()
    z[2] = min(z[2], math.log(0.9))
    z[3] = min(z[3], 0.5 * math.log(BETA_VAR_MARGIN * math.exp(z[2]) * (1 - math.exp(z[2]))))
    z[0] = np.clip(z[0], math.log(1e-3), math.log(1e5))
    z[1] = np.clip(z[1], z[0] + math.log(1e-3), z[0] + math.log(30.0))
    return z


def fit_sample(raster: Raster, law: LawSettings | None = None, iters: int = 12, h: float = 0.01) -> SampleFit:
    """Maximum of a sample's own likelihood, its observed information and learning rates.

    Damped Newton on each block (size, shape) from the sample's moments; every likelihood
    evaluation is one batched call over the 7-point finite-difference stencil of both blocks.

    Parameters
    ----------
    raster : Raster
        The measured sample.
    law : LawSettings, optional
        Laws, noise and raster.
    iters : int, optional
        Newton iterations at most.
    h : float, optional
        Finite-difference step in ln(moment).

    Returns
    -------
    SampleFit
    """
    law = law or LawSettings()
    m = raster.moments
    z = np.log([m[0], max(m[1], 1e-3 * m[0]), max(m[2], 2e-3), max(m[3], 2e-3)])
    z = _z_feasible(z)
    blocks = ((0, 1), (2, 3))

    def evaluate(zc):
        Z = np.repeat(zc[None, :], 7, axis=0)
        Z[:, 0:2] += h * _STENCIL
        Z[:, 2:4] += h * _STENCIL
        X = np.exp(Z)
        cs = size_cell_logp(raster, X[:, 0], X[:, 1], law)
        cr = shape_cell_logp(raster, X[:, 2], X[:, 3], law)
        rc = np.concatenate([[raster.r_zero], raster.r_counts])
        return [_block_derivs(cs, raster.s_counts, h), _block_derivs(cr, rc, h)]

    step_scale = np.ones(2)
    d = evaluate(z)
    done = np.zeros(2, dtype=bool)
    for _ in range(iters):
        znew = z.copy()
        for b, (i, j) in enumerate(blocks):
            if done[b]:
                continue
            _, g, H, _ = d[b]
            negH = -H
            if np.all(np.linalg.eigvalsh(negH) > 1e-9):
                step = np.linalg.solve(negH, g)
                if float(g @ step) < 1e-4:  # Newton decrement: within 1e-4 of the maximum
                    done[b] = True
                    continue
            else:
                step = 0.05 * g / max(np.linalg.norm(g), 1e-12)
            nrm = np.linalg.norm(step)
            if nrm > 0.5:
                step *= 0.5 / nrm
            znew[[i, j]] = z[[i, j]] + step_scale[b] * step
        if done.all():
            break
        znew = _z_feasible(znew)
        dn = evaluate(znew)
        for b, (i, j) in enumerate(blocks):
            if done[b]:
                continue
            if dn[b][0] >= d[b][0] - 1e-9:  # accept: the block's value did not drop
                z[[i, j]] = znew[[i, j]]
                d[b] = dn[b]
                step_scale[b] = min(1.0, step_scale[b] * 2)
            else:
                step_scale[b] *= 0.5
    info = np.zeros((4, 4))
    eta = np.ones(2)
    ok = np.zeros(2, dtype=bool)
    rc = np.concatenate([[raster.r_zero], raster.r_counts])
    for b, ((i, j), counts) in enumerate(zip(blocks, (raster.s_counts, rc))):
        _, g, H, scores = d[b]
        I = -H
        if np.all(np.linalg.eigvalsh(I) > 1e-9) and np.all(np.isfinite(I)):
            ok[b] = True
            info[np.ix_([i, j], [i, j])] = I
            J = (scores * counts[:, None]).T @ scores
            try:
                eta[b] = float(np.trace(I @ np.linalg.solve(J, I)) / np.trace(I))
            except np.linalg.LinAlgError:
                eta[b] = 1.0
    return SampleFit(z, info, np.clip(eta, 0.0, 1.0), ok)
