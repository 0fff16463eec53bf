"""Laws of one impact that the plant and the moment model share: impact energies (eqn 5),
the tribological and plasticity factors (eqn 9), the dissipated share (eqns 7, 8, 10), the
incidence-angle law of the impacts a collision runs, and the hit rate.

The plant's event kernels (:mod:`bmctl.plant.events`, :mod:`bmctl.plant.kernels`) draw with
the same laws; ``tests/physics`` checks that both give the same draws from the same generator.
"""

from __future__ import annotations

import math

import numpy as np

from .constants import MEAN_LOSS_RATIO
from .kinematics import Kinematics


def sample_impact_energies(rng, theta, n, weighted=True):
    """Draw ``n`` impact-energy pairs U_in > U_out from Gamma(3/2, theta).  (5)

    With ``weighted`` the pairs are drawn in proportion to the share of particles
    that collision processes, (U_in - U_out) / U_in (docs/model.md, Sec. 3.2).

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the draws.
    theta : float
        Gamma scale (J).
    n : int
        Number of pairs.
    weighted : bool, optional
        Weight the pairs by (U_in - U_out) / U_in.

    Returns
    -------
    u_in, u_out : ndarray
    """
    out_in = np.empty(0)
    out_out = np.empty(0)
    while out_in.size < n:
        m = max(16, int(2.2 * (n - out_in.size)) + 8)
        g = rng.gamma(1.5, theta, size=(2, m))
        hi = np.maximum(g[0], g[1])
        lo = np.minimum(g[0], g[1])
        if weighted:
            keep = rng.random(m) * hi < hi - lo
            hi, lo = hi[keep], lo[keep]
        out_in = np.concatenate([out_in, hi])
        out_out = np.concatenate([out_out, lo])
    return out_in[:n], out_out[:n]


def sample_zeta(rng, alpha, n):
    """Tribological factor zeta ~ Beta(2, alpha + 1): p = (a+1)(a+2) z (1-z)^a.  (9)"""
    return rng.beta(2.0, alpha + 1.0, size=n)


def sample_xi(rng, beta, n):
    """Plasticity factor xi ~ Beta(beta + 1, 2): p = (b+1)(b+2) x^b (1-x).  (9)"""
    return rng.beta(beta + 1.0, 2.0, size=n)


def dissipation_coefficients(alpha: float, beta: float) -> tuple[float, float]:
    """(a, b) with E[dissipated share | psi] = a sin^2(2 psi) + b cos^2(2 psi).  (7)-(9)

    a = 1 - E[zeta^2], zeta ~ Beta(2, alpha + 1); b = 1 - E[xi^2], xi ~ Beta(beta + 1, 2).

    Parameters
    ----------
    alpha, beta : float
        The exponents of (9).
    """
    ez2 = 2 * 3 / ((alpha + 3) * (alpha + 4))
    ex2 = (beta + 1) * (beta + 2) / ((beta + 3) * (beta + 4))
    return 1.0 - ez2, 1.0 - ex2


def sample_impact_angles(rng: np.random.Generator, a: float, b: float, n: int) -> np.ndarray:
    """Incidence angles psi of the impacts a collision runs: density ~ 1 / (a sin^2 2psi + b cos^2 2psi).

    Exact transform of one uniform draw phi ~ U(-pi, pi): 2 psi = atan2(sqrt(b) sin phi, sqrt(a) cos phi).

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the n uniform draws.
    a, b : float
        :func:`dissipation_coefficients`.
    n : int
        Number of angles.
    """
    ca, sb = _angle_components(rng, a, b, n)
    return 0.5 * np.arctan2(sb, ca)


def _angle_components(rng: np.random.Generator, a: float, b: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(sqrt(a) cos phi, sqrt(b) sin phi) of n uniform draws phi ~ U(-pi, pi): 2 psi is their angle."""
    phi = rng.uniform(-np.pi, np.pi, size=n)
    return math.sqrt(a) * np.cos(phi), math.sqrt(b) * np.sin(phi)


def sample_impact_cos2psi(rng: np.random.Generator, a: float, b: float, n: int) -> np.ndarray:
    """cos 2psi of the angles :func:`sample_impact_angles` draws, from the same draws, without atan2.

    2 psi = atan2(sqrt(b) sin phi, sqrt(a) cos phi), so cos 2 psi = sqrt(a) cos phi / sqrt(a cos^2 phi
    + b sin^2 phi): the impact physics needs psi only through cos 2 psi (eqns 7, 8, 14).

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the n uniform draws.
    a, b : float
        :func:`dissipation_coefficients`.
    n : int
        Number of angles.

    Examples
    --------
    >>> import numpy as np
    >>> c = sample_impact_cos2psi(np.random.default_rng(0), 0.8, 0.6, 4)
    >>> psi = sample_impact_angles(np.random.default_rng(0), 0.8, 0.6, 4)
    >>> bool(np.allclose(c, np.cos(2 * psi)))
    True
    """
    ca, sb = _angle_components(rng, a, b, n)
    return ca / np.sqrt(ca * ca + sb * sb)


def hit_rate(alpha: float, beta: float, kin: Kinematics) -> float:
    """Impacts per particle per second: f F_t E[(U_in - U_out)/U_in] E[1/c(psi)], E[1/c] = 1/sqrt(a b).

    The rate of the plant's paper kernels (:class:`bmctl.plant.kernels.PaperKernels`).

    Parameters
    ----------
    alpha, beta : float
        The card's exponents of (9).
    kin : Kinematics
        Frequency f and trapped share F_t at the rpm.
    """
    if kin.frequency == 0:
        return 0.0
    a, b = dissipation_coefficients(alpha, beta)
    return kin.frequency * kin.trapped_fraction * MEAN_LOSS_RATIO / math.sqrt(a * b)
