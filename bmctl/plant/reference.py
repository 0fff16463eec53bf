"""One collision at a time: the paper's stochastic model read literally (Sec. 3.2-3.4), for verification.

Slow, plain Python; used only by :mod:`bmctl.validation` and the tests. For each collision of
the mill (steadily timed, Sec. 3.2): draw U_in > U_out from (5) and one incidence angle psi;
Delta U = U_in - U_out. Then repeat, while Delta U > 0: pick particle i and a second
particle j by the population fractions p (uniformly from the sample), and run one impact
on the pair with :meth:`bmctl.plant.kernels.PaperKernels.impact` (zeta, xi per particle,
(6)-(10), shape change (11)-(14), fracture (20) of either particle, bonding (15)-(18) if
neither broke); spend the heat both dissipated, Delta U <- Delta U - Delta U_d,i - Delta U_d,j
(10). Then the next collision.

The sample has a constant weight w (real particles per simulated one) and a varying size:
a bond removes a particle, a fracture adds one, with no rebalancing. It stands for the
vial's N = w n particles, so the mill's collisions reach it at the rate f / w; each
collision spends its full Delta U on the sample (``budget_scale`` = 1), so the steps of one
collision, about F_t N (U_in - U_out) / (2 U_in c) of them, share U_in and psi as in the
vial. Thermal state (temperature, hardening) follows the same exact first-order updates as
the plant, at each collision.

What differs from the batched plant (:class:`bmctl.plant.plant.Plant`), and is therefore
what a comparison checks: impacts one after another with the population as it is at that
moment, pairs drawn by p without any batching, the impact energies and angles weighted only
by the loop's own stopping rule, and no constant-number rebalancing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..config import ModelCard
from . import events as ev
from . import thermal
from .kernels import PaperKernels
from .kinematics import Kinematics, kinematics
from .population import initial_sample, moments


@dataclass
class ReferenceCounts:
    """Counters of a reference run.

    Attributes
    ----------
    collisions, impacts, bonds, fractures : int
        Collisions, impacts (pair steps) and events so far.
    """

    collisions: int = 0
    impacts: int = 0
    bonds: int = 0
    fractures: int = 0


class ReferencePlant:
    """The paper's loop, one collision and one pair at a time, on a constant-weight sample.

    Parameters
    ----------
    card : ModelCard
        Parameters (the plant's model card).
    rng : numpy.random.Generator
        The single source of randomness.
    particles : int, optional
        Initial sample size (default: the card's).
    budget_scale : float, optional
        Share of each collision's Delta U spent on the sample, with collisions reaching it
        ``1 / budget_scale`` times more often (1: the vial's collisions as they are).

    Attributes
    ----------
    s, r : list of float
        Sizes (m) and aspect ratios of the sample (its length changes).
    weight : float
        Real particles per simulated particle, w = N(0) / M (constant).
    """

    def __init__(self, card: ModelCard, rng: np.random.Generator, particles: int | None = None,
                 budget_scale: float = 1.0):
        if not budget_scale > 0:
            raise ValueError(f"budget_scale must be > 0 (got {budget_scale})")
        self.card = card
        self.rng = rng
        M = int(particles or card.simulation.particles)
        init = card.initial
        s, r = initial_sample(rng, M, init.s_mean_um, init.s_std_um, init.r_mean)
        mat, mill = card.material, card.mill
        self.powder_kg = mill.ball_count * mat.impactor_mass_kg / mill.ball_to_powder_ratio
        n_real = self.powder_kg / (mat.powder_density_kg_m3 * math.pi / 6 * np.mean(s**3))
        self.total_area = float(n_real * np.mean(s**2))  # X, as the plant computes it
        self.weight = float(n_real / M)
        self.s, self.r = s.tolist(), r.tolist()
        self.t_s = 0.0
        self.temperature_C = card.thermal.ambient_C
        self.hardening = 0.0
        self.counts = ReferenceCounts()
        self.budget_scale = float(budget_scale)
        st = card.stochastic
        self._gamma = st.gamma_per_um2 * 1e12  # (15), as the plant
        self._delta = st.delta_per_um2 * 1e12  # (20)
        self._physics = PaperKernels(samplers="exact")  # the paper's loop draws as printed
        self._next_collision = None  # time (s) of the next collision while milling at one rpm

    # --- the attributes PaperKernels.impact reads --------------------------------------------
    def effective_yield_stress(self) -> float:
        """sigma_eff at the current temperature and hardening."""
        return thermal.effective_yield_stress(
            self.card.material.yield_stress_Pa, self.temperature_C, self.hardening, self.card.thermal
        )

    @property
    def M(self) -> int:
        """Current sample size."""
        return len(self.s)

    @property
    def represented_particles(self) -> float:
        """N = w n."""
        return self.weight * len(self.s)

    # --- dynamics ------------------------------------------------------------------------------
    def advance(self, rpm: float, hours: float) -> None:
        """Mill at ``rpm`` for ``hours``, collision by collision.

        Parameters
        ----------
        rpm : float
            Sun-disc speed; 0 is a rest (temperature and hardening only).
        hours : float
            Length of the interval (h).
        """
        kin = kinematics(self.card, rpm)
        end = self.t_s + hours * 3600.0
        if kin.frequency == 0:
            self._thermal(kin, end - self.t_s)
            return
        period = self.budget_scale * self.weight / kin.frequency  # the vial's collisions, as seen by the sample
        t_next = self.t_s + period * self.rng.random()  # phase of the steady collision clock
        while t_next < end:
            self._thermal(kin, t_next - self.t_s)
            self.collision(kin)
            t_next += period
        self._thermal(kin, end - self.t_s)

    def _thermal(self, kin: Kinematics, dt: float) -> None:
        th = self.card.thermal
        p = kin.mean_power_W
        self.temperature_C = thermal.step_temperature(self.temperature_C, p, dt, th)
        self.hardening = thermal.step_hardening(self.hardening, p, self.powder_kg, dt, th)
        self.t_s += dt

    def collision(self, kin: Kinematics) -> int:
        """One collision: U_in > U_out from (5) and psi, then impacts until Delta U is spent.

        Parameters
        ----------
        kin : Kinematics
            Collision quantities at the current rpm.

        Returns
        -------
        int
            The number of pair steps it took.
        """
        rng = self.rng
        u_in, u_out = ev.sample_impact_energies(rng, kin.energy_scale, 1, weighted=False)  # (5)
        psi = rng.uniform(-np.pi / 2, np.pi / 2, size=1)
        budget = self.budget_scale * float(u_in[0] - u_out[0])
        steps = 0
        while budget > 0 and len(self.s) >= 2:
            budget -= self.step(kin, u_in, psi)
            steps += 1
        self.counts.collisions += 1
        return steps

    def step(self, kin: Kinematics, u_in: np.ndarray, psi: np.ndarray) -> float:
        """One impact on particles i, j picked by p; returns the heat they dissipated (10).

        Parameters
        ----------
        kin : Kinematics
            Collision quantities at the current rpm.
        u_in, psi : ndarray, shape (1,)
            The collision's incident energy (J) and incidence angle.
        """
        rng, s, r = self.rng, self.s, self.r
        n = len(s)
        i = int(rng.integers(n))
        j = (i + 1 + int(rng.integers(n - 1))) % n  # uniform over the others
        out, dud = self._physics.impact(self, kin, np.array([s[i]]), np.array([r[i]]), np.array([s[j]]),
                                        np.array([r[j]]), u_in, np.cos(2 * psi), rng)
        r[i], r[j] = float(out.r[0]), float(out.r[1])
        self.counts.impacts += 1
        if out.frac.any():  # (20): part 1 stays, part 2 is a new particle
            for k, slot in enumerate(np.flatnonzero(out.frac)):
                idx = i if slot == 0 else j
                s[idx], r[idx] = float(out.s1[k]), float(out.r1[k])
                s.append(float(out.s2[k]))
                r.append(float(out.r2[k]))
            self.counts.fractures += int(out.frac.sum())
        elif out.bond[0]:  # (15)-(18): i becomes the bonded particle, j leaves the sample
            s[i], r[i] = float(out.s_bond[0]), float(out.r_bond[0])
            s[j], r[j] = s[-1], r[-1]
            s.pop()
            r.pop()
            self.counts.bonds += 1
        return float(dud[0])

    # --- observation ---------------------------------------------------------------------------
    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """Sizes (m) and aspect ratios as arrays."""
        return np.array(self.s), np.array(self.r)

    def moments(self) -> dict:
        """Mean/std/mode of s (um) and r, as :meth:`bmctl.plant.plant.Plant.moments`."""
        s, r = self.arrays()
        m = moments(s, r)
        m.update(t_h=self.t_s / 3600.0, temperature_c=self.temperature_C, hardening=self.hardening)
        return m


__all__ = ["ReferencePlant", "ReferenceCounts"]
