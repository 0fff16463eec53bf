"""Card-derived constants of the moment model (plain floats, computed once per card).

Everything that the plant computes from the card and the rpm and that does not depend
on the particle population is reduced here to a few scalars and exact power laws in
rpm (Burgio kinematics: v ~ rpm, so f ~ rpm, theta ~ rpm^2, the Hertz contact radius
~ v^0.4, the trapped share ~ rpm^0.8, the impact rate per particle ~ rpm^1.8 and the
mean dissipated power ~ rpm^3). The random factors of one impact (Gamma impact
energies, incidence angle, zeta, xi) are averaged once by a seeded quadrature-grade
Monte Carlo and summarised as logistic laws in log intensity (docs/moments.md, Sec. 2).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from functools import lru_cache

import numpy as np

from ..config import ModelCard
from ..physics import impacts as ev
from ..physics.kinematics import kinematics

UM = 1e-6
#: exponents of the exact rpm power laws (Burgio et al. 1991, Maurice & Courtney 1990)
EXP_POWER = 3.0
EXP_RATE = 1.8
EXP_TRAPPED = 0.8
#: probability bins of the random plastic energy of one impact (rounding law), finer in the lower
#: tail that dominates E[exp(-lam Z)] when lam is large
ROUND_BINS = (0.0, 0.02, 0.06, 0.15, 0.3, 0.5, 0.75, 1.0)
CONTACT_BINS = (0.0, 0.25, 0.5, 0.75, 1.0)  # quantile bins of sqrt(U_in / E[U_in]) (contact length, eqn 16)


@dataclass(frozen=True)
class Constants:
    """Scalars of one card that the moment equations need (SI unless suffixed).

    Attributes
    ----------
    rpm_max : float
        Mill's top speed; rpm is scaled by it inside the model.
    power_max_W : float
        Mean dissipated power at ``rpm_max``; P(rpm) = power_max_W (rpm/rpm_max)^3.
    rate_max_per_h : float
        Impacts per particle per hour at ``rpm_max``; k(rpm) = rate_max_per_h (rpm/rpm_max)^1.8.
    e_max_J_per_um2 : float
        Mean impact energy per particle, divided by s^2 (s in um), at ``rpm_max``:
        share * E[U_in] / A_trapped; scales as (rpm/rpm_max)^1.2.
    u_mean_max_J : float
        Mean (loss-weighted) incident energy E[U_in] at ``rpm_max``; scales as (rpm/rpm_max)^2.
    modulus_Pa, yield_Pa, u_J_per_m : float
        Material constants E, sigma and the bonding threshold u.
    gamma_per_um2, delta_per_um2 : float
        Contact and fracture factors of eqns (15) and (20).
    plastic_share : float
        E[cos^2(2 psi)(1 - xi^2)] / E[dissipated share]: the plastic part of the dissipated energy.
    equiaxing, equiaxing_hardening : float
        eta_eq and a of the rounding law (after eqn 13): efficiency eta_eq (1 - a h)^+.
    round_nodes : tuple of (weight, z)
        Probabilities and conditional means of the plastic energy Z of one impact relative
        to its mean, over ROUND_BINS: E[1 - exp(-lam Z)] ~ sum_k w_k (1 - exp(-lam z_k)).
    contact_nodes : tuple of (weight, f)
        Probabilities and conditional means of f = sqrt(U_in / E[U_in]) over CONTACT_BINS:
        the Hertz contact length of eqn 16 is d_mean f, so the r of a new bond (eqn 18) is
        averaged over them (equations.bond_r_moments).
    ambient_C, heat_capacity_J_per_K, cooling_time_h : float
        Vial thermal model.
    softening_max, softening_scale_K, hardening_max : float
        Yield-stress model.
    hardening_rate_max_per_h : float
        P(rpm_max) / (m_p W_h) in 1/h.
    recovery_time_h : float
        Static recovery time of hardening.
    n_bond, n_frac : float
        Threshold exponents of thermal.thresholds.
    s0_mean_um, s0_std_um, r0_mean : float
        Initial powder (card).
    """

    rpm_max: float
    power_max_W: float
    rate_max_per_h: float
    e_max_J_per_um2: float
    u_mean_max_J: float
    modulus_Pa: float
    yield_Pa: float
    u_J_per_m: float
    gamma_per_um2: float
    delta_per_um2: float
    plastic_share: float
    equiaxing: float
    equiaxing_hardening: float
    ambient_C: float
    heat_capacity_J_per_K: float
    cooling_time_h: float
    softening_max: float
    softening_scale_K: float
    hardening_max: float
    hardening_rate_max_per_h: float
    recovery_time_h: float
    n_bond: float
    n_frac: float
    s0_mean_um: float
    s0_std_um: float
    r0_mean: float
    round_nodes: tuple = ((1.0, 1.0),)
    contact_nodes: tuple = ((1.0, 1.0),)

    def as_dict(self) -> dict:
        return asdict(self)


def _impact_angles(rng, alpha: float, beta: float, n: int) -> np.ndarray:
    """The impact angles the plant's kernels draw (:func:`bmctl.physics.impacts.sample_impact_angles`)."""
    return ev.sample_impact_angles(rng, *ev.dissipation_coefficients(alpha, beta), n)


@lru_cache(maxsize=8)
def impact_factors(alpha: float, beta: float, n: int = 400_000, seed: int = 12345) -> dict:
    """Scale-free averages of one impact's random factors (seeded Monte Carlo, cached).

    Returns a dict with ``u_mean`` (E[U_in]/theta under the loss weighting of eqn 5),
    ``share`` (mean dissipated share, eqns 7-10), ``plastic`` (mean plastic share) and
    samples' log-factors ``zb``, ``zc`` of the bonding and fracture intensities relative
    to their deterministic values (used to derive the logistic laws).
    """
    rng = np.random.default_rng(seed)
    u_in, _ = ev.sample_impact_energies(rng, 1.0, n)
    psi = _impact_angles(rng, alpha, beta, n)
    share = []
    for _ in range(2):
        z = ev.sample_zeta(rng, alpha, n)
        x = ev.sample_xi(rng, beta, n)
        share.append(np.sin(2 * psi) ** 2 * (1 - z**2) + np.cos(2 * psi) ** 2 * (1 - x**2))
    share_mean = float(share[0].mean())
    ex2 = (beta + 1) * (beta + 2) / ((beta + 3) * (beta + 4))
    plastic = float(np.mean(np.cos(2 * psi) ** 2)) * (1 - ex2)
    u_mean = float(u_in.mean())
    plastic_z = u_in / u_mean * np.cos(2 * psi) ** 2 * (1 - ev.sample_xi(rng, beta, n) ** 2)
    plastic_z /= plastic_z.mean()
    qs = np.quantile(plastic_z, ROUND_BINS)
    idx = np.clip(np.searchsorted(qs, plastic_z, side="right") - 1, 0, len(ROUND_BINS) - 2)
    round_nodes = tuple((float(np.mean(idx == k)), float(plastic_z[idx == k].mean())) for k in range(len(ROUND_BINS) - 1))
    sq = np.sqrt(u_in / u_mean)
    qd = np.quantile(sq, CONTACT_BINS)
    jd = np.clip(np.searchsorted(qd, sq, side="right") - 1, 0, len(CONTACT_BINS) - 2)
    contact_nodes = tuple((float(np.mean(jd == k)), float(sq[jd == k].mean())) for k in range(len(CONTACT_BINS) - 1))
    zb = np.log(np.sqrt(u_in / u_mean) * (share[0] + share[1]) / (2 * share_mean))
    zc = np.log(u_in / u_mean * share[0] / share_mean)
    return {"u_mean": u_mean, "share": share_mean, "plastic": plastic, "zb": zb, "zc": zc,
            "round_nodes": round_nodes, "contact_nodes": contact_nodes}


def logistic_law(logz: np.ndarray, sharpness: float) -> tuple[float, float]:
    """Fit E[sigmoid(k (rho Z - 1))] ~ sigmoid(a ln rho + o) over the random factor Z.

    ``k`` is the sharpness of eqn (17). Returns (a, o): the derived slope and offset of the
    averaged threshold law in log intensity.
    """
    from scipy.optimize import least_squares

    lr = np.linspace(-3.0, 3.0, 61)
    z = np.exp(logz[:50_000])
    target = np.array([np.mean(1.0 / (1.0 + np.exp(-np.clip(sharpness * (math.exp(v) * z - 1), -60, 60)))) for v in lr])

    def res(q):
        return 1.0 / (1.0 + np.exp(-(q[0] * lr + q[1]))) - target

    sol = least_squares(res, [2.0, 0.0])
    return float(sol.x[0]), float(sol.x[1])


def plant_hit_rate(card: ModelCard, kin) -> float:
    """Impacts per particle per second of the plant's paper kernels at ``kin`` (:func:`bmctl.physics.impacts.hit_rate`)."""
    return float(ev.hit_rate(card.stochastic.alpha, card.stochastic.beta, kin))


def initial_area_m2(card: ModelCard) -> float:
    """Represented total s^2 (eqn 2) of the card's powder, from the Gaussian initial law's moments."""
    init, mat, mill = card.initial, card.material, card.mill
    m, sd = init.s_mean_um * UM, init.s_std_um * UM
    powder_kg = mill.ball_count * mat.impactor_mass_kg / mill.ball_to_powder_ratio
    es2, es3 = m**2 + sd**2, m**3 + 3 * m * sd**2
    n_real = powder_kg / (mat.powder_density_kg_m3 * math.pi / 6 * es3)
    return n_real * es2


def constants(card: ModelCard) -> Constants:
    """Reduce ``card`` to the scalars of the moment model."""
    mill, mat, st, th, part = card.mill, card.material, card.stochastic, card.thermal, card.partition
    kin = kinematics(card, mill.rpm_max)
    f = impact_factors(float(st.alpha), float(st.beta))
    rate = plant_hit_rate(card, kin)  # 1/s
    area = initial_area_m2(card)
    u_mean = f["u_mean"] * kin.energy_scale
    e_max = f["share"] * u_mean / (kin.trapped_fraction * area) * UM**2  # J per um^2 of s^2
    powder_kg = mill.ball_count * mat.impactor_mass_kg / mill.ball_to_powder_ratio
    return Constants(
        rpm_max=float(mill.rpm_max),
        power_max_W=float(kin.mean_power_W),
        rate_max_per_h=float(rate * 3600.0),
        e_max_J_per_um2=float(e_max),
        u_mean_max_J=float(u_mean),
        modulus_Pa=float(mat.elastic_modulus_Pa),
        yield_Pa=float(mat.yield_stress_Pa),
        u_J_per_m=float(mat.bond_threshold_J_per_m),
        gamma_per_um2=float(st.gamma_per_um2),
        delta_per_um2=float(st.delta_per_um2),
        plastic_share=float(f["plastic"] / f["share"]),
        equiaxing=float(part.equiaxing_efficiency),
        equiaxing_hardening=float(getattr(part, "equiaxing_hardening", 0.0)),
        ambient_C=float(th.ambient_C),
        heat_capacity_J_per_K=float(th.heat_capacity_J_per_K),
        cooling_time_h=float(th.cooling_time_s / 3600.0),
        softening_max=float(th.softening_max),
        softening_scale_K=float(th.softening_scale_K),
        hardening_max=float(th.hardening_max),
        hardening_rate_max_per_h=float(kin.mean_power_W / (powder_kg * th.hardening_work_J_per_kg) * 3600.0),
        recovery_time_h=float(th.recovery_time_s / 3600.0),
        n_bond=float(th.bond_hardening_exponent),
        n_frac=float(th.fracture_hardening_exponent),
        s0_mean_um=float(card.initial.s_mean_um),
        s0_std_um=float(card.initial.s_std_um),
        r0_mean=float(card.initial.r_mean),
        round_nodes=f["round_nodes"],
        contact_nodes=f["contact_nodes"],
    )


def derived_threshold_laws(card: ModelCard) -> dict[str, float]:
    """Slopes and offsets of the averaged bonding and fracture threshold laws (eqn 17 over 5, 7-9)."""
    st, part = card.stochastic, card.partition
    f = impact_factors(float(st.alpha), float(st.beta))
    ab, ob = logistic_law(f["zb"], part.threshold_sharpness)
    ac, oc = logistic_law(f["zc"], part.threshold_sharpness)
    return {"bond_slope": ab, "bond_offset": ob, "frac_slope": ac, "frac_offset": oc}
