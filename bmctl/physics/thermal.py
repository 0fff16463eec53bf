"""Vial temperature, thermal softening and work hardening (beyond the paper; docs/model.md Sec. 4).

dT/dt = P / C - (T - T_amb) / tau            (heating by dissipated power, Newton cooling)
dh/dt = P / (m_p W_h) (1 - h) - h / tau_rec  (hardening by plastic work, slow recovery)
sigma_eff = sigma (1 + H h) (1 - S (1 - exp(-(T - T_amb) / T_s)))
u_bond = u (sigma_eff / sigma)^n_b,  u_fracture = u (sigma_eff / sigma)^-n_c

With S = 0 and H = 0 ("neutral") sigma_eff = sigma and both thresholds are the
paper's u: the steady-state model of Sec. 3.2.
"""

from __future__ import annotations

import math

from ..config import Thermal


def step_temperature(T_C: float, power_W: float, dt_s: float, th: Thermal) -> float:
    """Exact update of the first-order vial temperature over ``dt_s`` at constant power."""
    T_ss = th.ambient_C + power_W * th.cooling_time_s / th.heat_capacity_J_per_K
    return T_ss + (T_C - T_ss) * math.exp(-dt_s / th.cooling_time_s)


def step_hardening(h: float, power_W: float, powder_kg: float, dt_s: float, th: Thermal) -> float:
    """Exact update of the hardening state h in [0, 1) over ``dt_s`` at constant power."""
    a = power_W / (powder_kg * th.hardening_work_J_per_kg)
    b = 1.0 / th.recovery_time_s
    h_ss = a / (a + b)
    return h_ss + (h - h_ss) * math.exp(-(a + b) * dt_s)


def softening_factor(T_C: float, th: Thermal) -> float:
    """Thermal softening multiplier of the yield stress, 1 - S (1 - exp(-(T - T_amb)^+ / T_s))."""
    dT = max(T_C - th.ambient_C, 0.0)
    return 1.0 - th.softening_max * (1.0 - math.exp(-dT / th.softening_scale_K))


def effective_yield_stress(sigma: float, T_C: float, h: float, th: Thermal) -> float:
    """sigma_eff = sigma (1 + H h) (1 - S (1 - exp(-(T - T_amb) / T_s)))."""
    return sigma * (1.0 + th.hardening_max * h) * softening_factor(T_C, th)


def thresholds(u: float, T_C: float, h: float, th: Thermal) -> tuple[float, float]:
    """Bonding and fracture thresholds (J/m) at temperature ``T_C`` and hardening ``h``.

    Bonding needs plastic flow at the joint: u_b = u (sigma_eff / sigma)^n_b, lowered by
    heat and raised by hardening. Cracking is the reverse: u_c = u (sigma_eff / sigma)^-n_c,
    raised in hot ductile material and lowered in hardened, brittle material.
    """
    ratio = (1.0 + th.hardening_max * h) * softening_factor(T_C, th)
    return u * ratio**th.bond_hardening_exponent, u * ratio ** (-th.fracture_hardening_exponent)
