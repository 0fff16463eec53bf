"""Collision kernels of the plant: the paper's impact physics and simple verification kernels.

The plant's event machinery (:meth:`bmctl.plant.plant.Plant._impacts`: Poisson batches of
disjoint random pairs, constant-number rebalancing, weight bookkeeping) asks a
:class:`Kernels` object two things:

* ``rate(plant, kin)``: processings per particle per second (each impact of a batch
  processes the two particles of its pair);
* ``collide(plant, kin, s_i, r_i, s_j, r_j, rng)``: what a batch of impacts on the pairs
  (i, j) does, as an :class:`Outcome` (new aspect ratios, which particles broke and into
  what, which pairs bonded and into what).

:class:`PaperKernels` is the paper's physics, eqns (5)-(20) (the default of every plant).
:class:`PopulationKernels` holds simple kernels in the area coordinate x = s^2 with known
solutions (constant-kernel Smoluchowski, Ziff-McGrady breakage, the bonding kernel (15) on
its own), used by :mod:`bmctl.verify` to check the machinery (docs/verification.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable, Protocol

import numpy as np

from ..physics.impacts import (dissipation_coefficients, sample_impact_angles,  # eqns (7)-(9): one definition  # noqa: F401
                               sample_impact_cos2psi)

from ..errors import InputError
from ..physics import samplers as tab
from . import events as ev
from . import thermal
from .kinematics import MEAN_LOSS_RATIO, Kinematics

if TYPE_CHECKING:  # pragma: no cover
    from .plant import Plant


@dataclass
class Outcome:
    """What one batch of n impacts on pairs (i, j) did.

    Attributes
    ----------
    r : ndarray, shape (2n,)
        Aspect ratios of ``[i..., j...]`` after the impacts' shape change.
    frac : ndarray of bool, shape (2n,)
        Which of ``[i..., j...]`` broke.
    s1, r1 : ndarray
        The part of each broken particle that stays in its slot (order of ``frac``).
    s2, r2 : ndarray
        The other part of each broken particle (needs a slot: constant-number rebalancing).
    bond : ndarray of bool, shape (n,)
        Which pairs bonded (only pairs of which neither particle broke).
    s_bond, r_bond : ndarray
        The bonded particles (they take slot i; slot j is freed).
    """

    r: np.ndarray
    frac: np.ndarray
    s1: np.ndarray
    r1: np.ndarray
    s2: np.ndarray
    r2: np.ndarray
    bond: np.ndarray
    s_bond: np.ndarray
    r_bond: np.ndarray


class Kernels(Protocol):
    """What the plant's event machinery needs from the physics of an impact."""

    def rate(self, plant: "Plant", kin: Kinematics) -> float:
        """Processings per particle per second (0: no impacts).

        Parameters
        ----------
        plant : Plant
            The plant (its card and state).
        kin : Kinematics
            Collision quantities at the current rpm.
        """

    def collide(self, plant: "Plant", kin: Kinematics, s_i: np.ndarray, r_i: np.ndarray,
                s_j: np.ndarray, r_j: np.ndarray, rng: np.random.Generator) -> Outcome:
        """Outcome of impacts on pairs (i, j) that share no particle.

        Parameters
        ----------
        plant : Plant
            The plant (card, temperature, hardening, total area, represented number).
        kin : Kinematics
            Collision quantities at the current rpm.
        s_i, r_i, s_j, r_j : ndarray
            Sizes (m) and aspect ratios of the pairs' particles.
        rng : numpy.random.Generator
            Source of every draw.
        """


SAMPLERS = ("tabulated", "exact")  # how PaperKernels draws U_in (5) and zeta, xi (9)


class PaperKernels:
    """The paper's impact physics, eqns (5)-(20) with the energy partition of docs/model.md.

    Each impact processes its pair (i, j): energies (5), (6); friction and plastic heat
    (7)-(10); shape change (11)-(14) and rounding; fracture (20) of either particle first,
    then bonding (15)-(18) of the pair if neither broke. The impacts' U_in and psi are those
    of the loop "until Delta U is spent" (Sec. 3.2): a collision runs about
    (Delta U / U_in) / c(psi) impacts, so U_in is drawn with weight Delta U / U_in (5) and psi
    with weight 1 / c(psi) (:func:`sample_impact_angles`).

    Parameters
    ----------
    samplers : {"tabulated", "exact"}, optional
        How U_in (5) and zeta, xi (9) are drawn: ``"tabulated"`` (default) inverts the laws'
        CDFs from tables, one uniform draw per variate (:mod:`bmctl.physics.samplers`);
        ``"exact"`` uses numpy's Gamma and Beta samplers (:mod:`bmctl.physics.impacts`), the
        streams of bmctl 0.x before the tables. Same laws (KS-tested); different streams.

    Examples
    --------
    >>> PaperKernels().samplers
    'tabulated'
    >>> PaperKernels(samplers="exact").samplers
    'exact'
    """

    def __init__(self, samplers: str = "tabulated"):
        if samplers not in SAMPLERS:
            raise InputError(f"samplers: must be one of {', '.join(SAMPLERS)} (got {samplers!r})")
        self.samplers = samplers

    def rate(self, plant: "Plant", kin: Kinematics) -> float:
        """Impacts per particle per second: f F_t E[(U_in - U_out)/U_in] E[1/c(psi)], E[1/c] = 1/sqrt(a b).

        Parameters
        ----------
        plant : Plant
            Supplies the card's alpha, beta.
        kin : Kinematics
            Frequency f and trapped share F_t at the current rpm.
        """
        if kin.frequency == 0:
            return 0.0
        a, b = dissipation_coefficients(plant.card.stochastic.alpha, plant.card.stochastic.beta)
        return kin.frequency * kin.trapped_fraction * MEAN_LOSS_RATIO / math.sqrt(a * b)

    def sample_cos2psi(self, plant: "Plant", rng: np.random.Generator, n: int) -> np.ndarray:
        """cos 2psi of the incidence angles of ``n`` impacts (:func:`sample_impact_cos2psi`: the angles of
        :func:`sample_impact_angles`, from the same draws).

        Parameters
        ----------
        plant : Plant
            Supplies the card.
        rng : numpy.random.Generator
            Source of the draws.
        n : int
            Number of impacts.
        """
        return sample_impact_cos2psi(rng, *dissipation_coefficients(plant.card.stochastic.alpha,
                                                                    plant.card.stochastic.beta), n)

    def sample_energies(self, rng: np.random.Generator, theta: float, n: int) -> np.ndarray:
        """U_in of ``n`` impacts under the weighted law of (5), by the kernels' ``samplers``.

        Parameters
        ----------
        rng : numpy.random.Generator
            Source of the draws.
        theta : float
            Gamma scale (J).
        n : int
            Number of impacts.
        """
        if self.samplers == "tabulated":
            return tab.tabulated_energies(rng, theta, n)  # (5)
        return ev.sample_impact_energies(rng, theta, n)[0]  # (5)

    def sample_zeta_xi(self, rng: np.random.Generator, alpha: float, beta: float,
                       n: int) -> tuple[np.ndarray, np.ndarray]:
        """``n`` tribological factors zeta, then ``n`` plasticity factors xi, by the kernels' ``samplers``.  (9)

        Parameters
        ----------
        rng : numpy.random.Generator
            Source of the draws.
        alpha, beta : float
            The exponents of (9).
        n : int
            Number of each.
        """
        if self.samplers == "tabulated":
            return tab.tabulated_zeta(rng, alpha, n), tab.tabulated_xi(rng, beta, n)
        return ev.sample_zeta(rng, alpha, n), ev.sample_xi(rng, beta, n)

    def collide(self, plant: "Plant", kin: Kinematics, si: np.ndarray, ri: np.ndarray,
                sj: np.ndarray, rj: np.ndarray, rng: np.random.Generator) -> Outcome:
        n = si.size
        u_in = self.sample_energies(rng, kin.energy_scale, n)  # (5)
        cos2psi = self.sample_cos2psi(plant, rng, n)
        return self.impact(plant, kin, si, ri, sj, rj, u_in, cos2psi, rng)[0]

    def impact(self, plant: "Plant", kin: Kinematics, si: np.ndarray, ri: np.ndarray, sj: np.ndarray,
               rj: np.ndarray, u_in: np.ndarray, cos2psi: np.ndarray,
               rng: np.random.Generator) -> tuple[Outcome, np.ndarray]:
        """Impacts with given incident energies U_in and angles psi (as cos 2 psi) on pairs (i, j), eqns (6)-(20).

        ``plant`` supplies the state: ``card``, ``total_area``, ``temperature_C``, ``hardening``,
        ``effective_yield_stress()`` and the factors ``_gamma``, ``_delta``. Returns the
        outcome and the heat each pair dissipated, Delta U_d,i + Delta U_d,j (10), which the
        one-collision-at-a-time reference (:mod:`bmctl.plant.reference`) spends from Delta U.

        Parameters
        ----------
        plant : Plant or ReferencePlant
            The state (see above).
        kin : Kinematics
            Collision quantities (trapped share).
        si, ri, sj, rj : ndarray
            Sizes (m) and aspect ratios of the pairs.
        u_in, cos2psi : ndarray
            Incident energy (J) and cos 2 psi (psi: incidence angle) of each impact.
        rng : numpy.random.Generator
            Source of zeta, xi and the event draws.
        """
        card = plant.card
        st, mat, part = card.stochastic, card.material, card.partition
        n = si.size
        trapped_area = kin.trapped_fraction * plant.total_area  # (6): u_in = U_in / A_trapped
        e_i = u_in * np.minimum(si**2 / trapped_area, 1.0)  # a particle gets at most the whole impact
        e_j = u_in * np.minimum(sj**2 / trapped_area, 1.0)
        zeta, xi = self.sample_zeta_xi(rng, st.alpha, st.beta, 2 * n)  # (9)
        c2 = np.concatenate([cos2psi, cos2psi])
        e2 = np.concatenate([e_i, e_j])
        dUf, dUp = ev.impact_heats(e2, c2, zeta, xi)  # (7), (8)
        dUd = dUf + dUp  # (10)

        sigma_eff = plant.effective_yield_stress()
        u_bond, u_frac = thermal.thresholds(mat.bond_threshold_J_per_m, plant.temperature_C, plant.hardening,
                                            card.thermal)
        s2 = np.concatenate([si, sj])
        r2 = np.concatenate([ri, rj])
        eps = ev.plastic_strain(dUp, s2, sigma_eff, part.strain_efficiency, c2, r2, part.max_strain)  # (11), (14)
        r2 = np.clip(r2 + ev.aspect_change(r2, eps), 0.0, ev.R_MAX)  # (13)
        r2 = ev.equiaxing(r2, dUp, s2, sigma_eff, part.equiaxing_efficiency,  # after (13)
                          plant.hardening, part.equiaxing_hardening)
        ri, rj = r2[:n], r2[n:]

        # fracture under the impact load first: (20), (17)
        x = rng.random(2 * n)
        dc = ev.crack_length(s2, x)
        pc = ev.fracture_probability(s2, r2, x, plant._delta)
        pu_c = ev.threshold_probability(dUd / np.maximum(dc, 1e-300), u_frac, part.threshold_sharpness)
        frac = rng.random(2 * n) < pc * pu_c
        s1, r1, s2b, r2b = ev.fractured(s2[frac], r2[frac], x[frac], dc[frac])

        # bonding of i with j if neither broke: (15)-(18)
        d = ev.hertz_contact_length(si, sj, u_in, mat.elastic_modulus_Pa)
        pu = ev.threshold_probability((dUd[:n] + dUd[n:]) / d, u_bond, part.threshold_sharpness)
        bond = (rng.random(n) < ev.bond_probability(si, ri, sj, rj, plant._gamma) * pu) & ~(frac[:n] | frac[n:])
        sb, rb = ev.bonded(si[bond], ri[bond], sj[bond], rj[bond], d[bond])
        return Outcome(r2, frac, s1, r1, s2b, r2b, bond, sb, rb), dUd[:n] + dUd[n:]


# --- verification kernels (area coordinate x = s^2) ------------------------------------------

BondProbability = Callable[[np.ndarray, np.ndarray, float], np.ndarray]
FractureProbability = Callable[[np.ndarray], np.ndarray]
Split = Callable[[np.random.Generator, int], np.ndarray]


def uniform_split(rng: np.random.Generator, n: int) -> np.ndarray:
    """Area fraction u ~ U(0, 1) of the first part: binary breakage, daughter density b(x|y) = 2/y.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the draws.
    n : int
        Number of fractions.
    """
    return rng.random(n)


@dataclass(frozen=True)
class PopulationKernels:
    """Verification kernels in the area coordinate x = s^2: bonding and breakage only.

    No energies, no shape change: r is left as it is (use r = 0). Each particle is
    processed at ``rate_per_s``; a processed particle breaks with probability
    ``fracture(x)`` into parts u x and (1 - u) x (u from ``split``), and a processed
    pair of which neither broke bonds with probability ``bond(x_i, x_j, N)`` (N: the
    represented number of particles) into x_i + x_j. Probabilities above 1 raise
    ``ValueError``: ``rate_per_s`` must be a majorant (a clipped probability would be a
    silent bias).

    Attributes
    ----------
    rate_per_s : float
        Processings per particle per second, rho.
    bond : callable, optional
        Bond probability per processed pair; agglomeration kernel K(x_i, x_j) = rho p / N.
    fracture : callable, optional
        Break probability per processing; selection rate S(x) = rho p.
    split : callable
        Draws the area fraction of the first part.
    """

    rate_per_s: float
    bond: BondProbability | None = None
    fracture: FractureProbability | None = None
    split: Split = uniform_split

    def rate(self, plant: "Plant", kin: Kinematics) -> float:
        """``rate_per_s`` while milling, 0 at rest."""
        return self.rate_per_s if kin.frequency > 0 else 0.0

    def collide(self, plant: "Plant", kin: Kinematics, si: np.ndarray, ri: np.ndarray,
                sj: np.ndarray, rj: np.ndarray, rng: np.random.Generator) -> Outcome:
        n = si.size
        s2 = np.concatenate([si, sj])
        r2 = np.concatenate([ri, rj])
        frac = np.zeros(2 * n, dtype=bool)
        s1 = r1 = s2b = r2b = np.empty(0)
        if self.fracture is not None:
            x = s2**2
            p = _checked(self.fracture(x), "fracture")
            u = self.split(rng, 2 * n)
            frac = rng.random(2 * n) < p
            s1, s2b = np.sqrt(u[frac] * x[frac]), np.sqrt((1.0 - u[frac]) * x[frac])
            r1, r2b = r2[frac], r2[frac]
        bond = np.zeros(n, dtype=bool)
        if self.bond is not None:
            n_rep = plant.total_area * plant.M / float(np.square(plant.s).sum())  # w M, without BLAS threads
            p = _checked(self.bond(si**2, sj**2, n_rep), "bond")
            bond = (rng.random(n) < p) & ~(frac[:n] | frac[n:])
        sb = np.sqrt(si[bond] ** 2 + sj[bond] ** 2)
        rb = np.zeros(sb.size)
        return Outcome(r2, frac, s1, r1, s2b, r2b, bond, sb, rb)


def _checked(p: np.ndarray, what: str) -> np.ndarray:
    p = np.asarray(p, dtype=float)
    if p.size and (p.max() > 1.0 + 1e-12 or p.min() < 0.0):
        raise ValueError(f"{what} probability outside [0, 1] (max {p.max():.3g}): raise rate_per_s")
    return p


def constant_agglomeration(K: float, N0: float, headroom: float = 1.0) -> PopulationKernels:
    """Constant Smoluchowski kernel K (per pair of real particles per second, unit volume).

    rho = headroom * K * N0 and p = K N / rho <= 1 while N <= headroom * N0.

    Parameters
    ----------
    K : float
        Kernel, per pair of real particles per second.
    N0 : float
        Represented number at the start.
    headroom : float, optional
        rho in units of K N0 (> 1 leaves room for the sampled N(0) and shortens the batches).
    """
    rho = headroom * K * N0
    return PopulationKernels(rate_per_s=rho, bond=lambda xi, xj, N: np.full(xi.shape, K * N / rho))


def linear_breakage(k: float, x_max: float, headroom: float = 1.0) -> PopulationKernels:
    """Binary breakage with selection rate S(x) = k x and uniform daughters (Ziff & McGrady 1985).

    rho = headroom * k * x_max, p = k x / rho <= 1 for x <= headroom * x_max.

    Parameters
    ----------
    k : float
        Rate constant, 1/(m^2 s).
    x_max : float
        Largest x (m^2) the population will hold.
    headroom : float, optional
        rho in units of k x_max.
    """
    rho = headroom * k * x_max
    return PopulationKernels(rate_per_s=rho, fracture=lambda x: k * x / rho)


def paper_bonding(gamma_per_m2: float, rate_per_s: float) -> PopulationKernels:
    """Bonding by eqn (15) alone, p_b = gamma s_i s_j (r = 0, p_u = 1), at ``rate_per_s`` processings.

    The agglomeration kernel is K(x_i, x_j) = rho min(gamma sqrt(x_i x_j), 1) / N.

    Parameters
    ----------
    gamma_per_m2 : float
        The factor gamma of (15), 1/m^2.
    rate_per_s : float
        Processings per particle per second, rho.
    """
    return PopulationKernels(
        rate_per_s=rate_per_s,
        bond=lambda xi, xj, N: ev.bond_probability(np.sqrt(xi), 0.0, np.sqrt(xj), 0.0, gamma_per_m2),  # (15)
    )
