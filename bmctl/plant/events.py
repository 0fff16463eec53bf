"""The paper's equations (1)-(20) as small vectorised functions (SI units).

Each function carries the equation number it implements; ``docs/model.md`` lists
the decisions taken where the printed formulas are loose.
"""

from __future__ import annotations

import numpy as np

from ..physics import libm
from ..physics.impacts import sample_impact_energies, sample_xi, sample_zeta  # eqns (5), (9): one definition  # noqa: F401

R_MAX = 0.99  # r is kept in [0, R_MAX] (r -> 1 is a fractal boundary, eqn 3)


# --- geometry ---------------------------------------------------------------------------------

def size_from_area(area):
    """Size s = 2 sqrt(A / pi) of a planar section of area A.  (1)"""
    return 2.0 * np.sqrt(np.asarray(area, dtype=float) / np.pi)


def aspect_from_perimeter(s, perimeter):
    """Aspect ratio r = 1 - pi s / L.  (3)"""
    return 1.0 - np.pi * np.asarray(s, dtype=float) / np.asarray(perimeter, dtype=float)


def perimeter_from_aspect(s, r):
    """Perimeter L = pi s / (1 - r), the inverse of (3)."""
    return np.pi * np.asarray(s, dtype=float) / (1.0 - np.asarray(r, dtype=float))


def ellipse_size_aspect(a, b):
    """Size and aspect ratio of an ellipse with half-axes a, b under the paper's L = pi (a + b).

    s = 2 sqrt(a b) (1) and r = 1 - 2 sqrt(a b) / (a + b) (3).
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    s = 2.0 * np.sqrt(a * b)
    return s, 1.0 - s / (a + b)


# --- energetics -------------------------------------------------------------------------------

def friction_heat(e_in, psi, zeta):
    """Friction heat Delta U_f = A u_in sin^2(2 psi)(1 - zeta^2), with A u_in = e_in.  (7)"""
    return e_in * np.sin(2 * psi) ** 2 * (1 - zeta**2)


def plastic_heat(e_in, psi, xi):
    """Plastic heat Delta U_p = A u_in cos^2(2 psi)(1 - xi^2), with A u_in = e_in.  (8)"""
    return e_in * np.cos(2 * psi) ** 2 * (1 - xi**2)


def impact_heats(e_in, cos2psi, zeta, xi):
    """Friction and plastic heat (7), (8) from cos 2 psi: sin^2 2psi = 1 - cos^2 2psi.  (7), (8)"""
    cos_sq = cos2psi * cos2psi
    return e_in * (1.0 - cos_sq) * (1 - zeta**2), e_in * cos_sq * (1 - xi**2)


def mean_dissipated_share(alpha, beta):
    """E[sin^2(2psi)(1-zeta^2) + cos^2(2psi)(1-xi^2)] under (9) and uniform psi.  (7), (8), (10)"""
    ez2 = 2 * 3 / ((alpha + 3) * (alpha + 4))  # E[zeta^2], zeta ~ Beta(2, alpha+1)
    ex2 = (beta + 1) * (beta + 2) / ((beta + 3) * (beta + 4))  # E[xi^2], xi ~ Beta(beta+1, 2)
    return 0.5 * (1 - ez2) + 0.5 * (1 - ex2)


# --- plastic shape change ----------------------------------------------------------------------

def critical_angle(r):
    """psi_c = atan(cot^2(omega/2)), omega = asin(1 - r): eps > 0 for |psi| < psi_c.  (14)"""
    c = np.sqrt(np.clip(1 - (1 - np.asarray(r, dtype=float)) ** 2, 0, 1))  # cos(omega)
    return np.arctan2(1 + c, 1 - c)


def strain_sign(cos2psi, r):
    """+1 where the impact flattens the particle, |psi| < psi_c (14); -1 elsewhere.

    With c = cos(omega), tan psi_c = (1 + c) / (1 - c) gives cos 2 psi_c = -2 c / (1 + c^2), and
    cos is decreasing on [0, pi], so |psi| < psi_c exactly where cos 2 psi > -2 c / (1 + c^2):
    :func:`critical_angle` without the arctangent.
    """
    c = np.sqrt(np.clip(1 - (1 - np.asarray(r, dtype=float)) ** 2, 0, 1))  # cos(omega)
    return np.where(np.asarray(cos2psi) > -2.0 * c / (1.0 + c * c), 1.0, -1.0)


def plastic_strain(dU_p, s, sigma, efficiency, cos2psi, r, max_strain):
    """Signed equivalent strain eps = +-eta_eps (3/2) Delta U_p / (A s sigma).  (11), sign by (14)

    ``efficiency`` (eta_eps) is the share of plastic heat that does shape-changing
    work (docs/model.md, eqn 11); |eps| is capped at ``max_strain``; ``cos2psi`` is cos 2 psi of
    the impact (:func:`strain_sign`).
    """
    area = np.pi / 4 * s**2
    mag = np.minimum(efficiency * 1.5 * dU_p / (area * s * sigma), max_strain)
    return strain_sign(cos2psi, r) * mag


def aspect_change(r, eps):
    """Delta r = (1 - r) sqrt(1 - (1 - r)^2) eps = sin(omega) cos(omega) eps.  (12), (13)"""
    return (1 - r) * np.sqrt(np.clip(1 - (1 - r) ** 2, 0, 1)) * eps


def equiaxing(r, dU_p, s, sigma, efficiency, hardening=0.0, hardening_decay=0.0):
    """Rounding of irregular particles by plastic work: r <- r exp(-eta_eq (3/2) dU_p / (A s sigma)).

    Not in the paper: Benjamin & Volin's (1974) equiaxed-particle stage of mechanical
    alloying, in which repeated impacts flatten the protrusions that welding and fracture
    leave; hardened material (higher sigma) rounds more slowly.
    ``efficiency`` = 0 switches it off (docs/model.md, after eqn 13).

    Work-hardened, embrittled material has used up its ductility: its protrusions crack off
    instead of flowing flat. The efficiency therefore decays with the hardening state h,
    eta_eq (1 - a h)^+ with a = ``hardening_decay`` (0, the default, keeps eta_eq constant).
    """
    area = np.pi / 4 * s**2
    eta = efficiency * max(0.0, 1.0 - hardening_decay * hardening)
    return r * libm.exp(-eta * 1.5 * dU_p / (area * s * sigma))  # the C library's exp, as the compiled engine


# --- bonding and fracture ---------------------------------------------------------------------

def bond_probability(s_i, r_i, s_j, r_j, gamma):
    """p_b = gamma s_i s_j / ((1 - r_i)(1 - r_j)), clipped to [0, 1]; gamma in 1/m^2.  (15)"""
    return np.clip(gamma * s_i * s_j / ((1 - r_i) * (1 - r_j)), 0.0, 1.0)


def hertz_contact_length(s_i, s_j, energy, modulus):
    """d_ij = 3/4 s_i s_j/(s_i+s_j) sqrt(3 pi U / (E (s_i^3 + s_j^3))), capped at pi/2 min(s_i, s_j).  (16)

    ``energy`` is the impactor's incident energy U_in, as printed; the cap keeps the
    contact within the smaller particle (docs/model.md, eqn 16).
    """
    d = 0.75 * s_i * s_j / (s_i + s_j) * np.sqrt(3 * np.pi * energy / (modulus * (s_i * s_i * s_i + s_j * s_j * s_j)))
    return np.minimum(d, np.pi / 2 * np.minimum(s_i, s_j))


def threshold_probability(du, u, sharpness):
    """p_u = 1 / (1 + exp(-k (du - u))) with k u = ``sharpness``.  (17)"""
    x = np.clip(sharpness * (du / u - 1.0), -60, 60)
    return 1.0 / (1.0 + libm.exp(-x))  # the C library's exp, as the compiled engine


def bonded(s_i, r_i, s_j, r_j, d):
    """Size and aspect ratio of the bonded particle; r clipped to [0, R_MAX].  (18), (2), (4)"""
    s = np.sqrt(s_i**2 + s_j**2)
    denom = s_i / (1 - r_i) + s_j / (1 - r_j) - 2 * d / np.pi
    r = 1 - s / np.maximum(denom, 1e-300)
    return s, np.clip(r, 0.0, R_MAX)


def fracture_probability(s, r, x, delta):
    """p_c = delta s^2/(1-r) x (1-x) for a split of area fraction x; delta in 1/m^2.  (20)"""
    return np.clip(delta * s**2 / (1 - r) * x * (1 - x), 0.0, 1.0)


def crack_length(s, x):
    """Length of the new boundary when a particle of size s splits off area fraction x.

    A chord approximation, exact for a half-split of a disc (d = s) and -> 0 as x -> 0
    (docs/model.md, eqn 20).
    """
    return 2 * s * np.sqrt(x * (1 - x))


def fractured(s, r, x, d):
    """Sizes and aspect ratios of the two parts of a fracture.  (2), (4), (18) reversed

    s_1 = s sqrt(x), s_2 = s sqrt(1 - x) (area conserved, eqn 2). Each part keeps its
    area share of the parent's perimeter plus one face of the crack,
    L_1 = x L + d, L_2 = (1 - x) L + d, so L_1 + L_2 = L + 2 d (eqn 4); a disc split in
    halves gives two exact half-discs (r = 0.136), a small chip comes out round.
    """
    L = np.pi * s / (1 - r)
    s1 = s * np.sqrt(x)
    s2 = s * np.sqrt(1 - x)
    r1 = np.clip(1 - np.pi * s1 / (x * L + d), 0.0, R_MAX)
    r2 = np.clip(1 - np.pi * s2 / ((1 - x) * L + d), 0.0, R_MAX)
    return s1, r1, s2, r2
