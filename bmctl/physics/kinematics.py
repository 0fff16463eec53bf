"""Planetary-mill kinematics: rpm -> impact velocity, energy scale, collision frequency, trapped powder.

References
----------
Burgio, N., Iasonna, A., Magini, M., Martelli, S., Padella, F. (1991). Mechanical
alloying of the Fe-Zr system. Correlation between input energy and end products.
Il Nuovo Cimento D 13, 459-476.  (ball velocity in a planetary mill)

Maurice, D. R., Courtney, T. H. (1990). The physics of mechanical alloying: a first
report. Metall. Trans. A 21, 289-303.  (Hertzian contact radius, powder trapped per impact)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

from ..config import ModelCard
from .constants import MEAN_ABS_DIFF_GAMMA15, MEAN_LOSS_RATIO


@dataclass(frozen=True)
class Kinematics:
    """Derived collision quantities at one rpm (all SI).

    Attributes
    ----------
    rpm : float
        Sun-disc speed.
    v_rms : float
        RMS impactor velocity v (m/s), Burgio et al. eqn for a planetary mill.
    energy_scale : float
        Scale theta of the Gamma(3/2, theta) impact-energy law (J); theta = m v^2 / 3
        so that the mean energy is m v^2 / 2 (docs/model.md, eqn 5).
    frequency : float
        Collision frequency f = Z v / l in the vial (1/s), Sec. 2.3.1.
    trapped_fraction : float
        Share of the powder caught in one collision's Hertzian contact zone.
    contact_radius : float
        Hertzian contact radius of a ball impact (m).
    """

    rpm: float
    v_rms: float
    energy_scale: float
    frequency: float
    trapped_fraction: float
    contact_radius: float

    @property
    def mean_power_W(self) -> float:
        """Mean dissipated power f * E[U_in - U_out] (W)."""
        return self.frequency * self.energy_scale * MEAN_ABS_DIFF_GAMMA15


def abs_diff_mean() -> float:
    """E|X - Y| for X, Y iid Gamma(3/2, 1) by quadrature: 2 E[max] - 2 E[X] (pinned as
    :data:`bmctl.physics.constants.MEAN_ABS_DIFF_GAMMA15`)."""
    import numpy as np
    from scipy import integrate, special

    pdf = lambda x: np.sqrt(x) * np.exp(-x) / special.gamma(1.5)  # noqa: E731
    cdf = lambda x: special.gammainc(1.5, x)  # noqa: E731
    emax = integrate.quad(lambda x: x * 2 * pdf(x) * cdf(x), 0, np.inf)[0]
    return 2 * emax - 2 * 1.5


def loss_ratio_mean() -> float:
    """E[(max - min) / max] for two iid Gamma(3/2) draws by nested quadrature (pinned as
    :data:`bmctl.physics.constants.MEAN_LOSS_RATIO`)."""
    import numpy as np
    from scipy import integrate, special

    pdf = lambda x: np.sqrt(x) * np.exp(-x) / special.gamma(1.5)  # noqa: E731
    inner = lambda hi: integrate.quad(lambda lo: (1 - lo / hi) * pdf(lo), 0, hi)[0]  # noqa: E731
    return integrate.quad(lambda hi: 2 * pdf(hi) * inner(hi), 0, np.inf, limit=200)[0]


__all__ = ["Kinematics", "kinematics", "ball_velocity", "coated_area", "MEAN_ABS_DIFF_GAMMA15", "MEAN_LOSS_RATIO",
           "abs_diff_mean", "loss_ratio_mean"]


def ball_velocity(rpm: float, mill) -> float:
    """Burgio et al. (1991) ball velocity in a planetary mill (m/s).

    v^2 = (W_p R_p)^2 + W_v^2 (R_v - d_b/2)^2 (1 - 2 W_v / W_p),
    with W_p the sun-disc and W_v = speed_ratio * W_p the vial angular velocity.
    """
    wp = 2 * math.pi * rpm / 60.0
    wv = mill.speed_ratio * wp
    rv = mill.vial_radius_m - mill.ball_diameter_m / 2
    v2 = (wp * mill.sun_radius_m) ** 2 + (wv * rv) ** 2 * (1 - 2 * mill.speed_ratio)
    return math.sqrt(max(v2, 0.0))


def coated_area(mill) -> float:
    """Surface that the powder coats: balls plus vial wall, floor and lid (m^2)."""
    balls = mill.ball_count * math.pi * mill.ball_diameter_m**2
    vial = 2 * math.pi * mill.vial_radius_m * mill.vial_height_m + 2 * math.pi * mill.vial_radius_m**2
    return balls + vial


def kinematics(card: ModelCard, rpm: float) -> Kinematics:
    """Collision quantities of ``card``'s mill at ``rpm`` (rpm 0: no collisions).

    Parameters
    ----------
    card : ModelCard
        Holds the mill geometry and the impactor mass.
    rpm : float
        Sun-disc speed (rev/min), 0 <= rpm.

    Returns
    -------
    Kinematics

    Examples
    --------
    >>> from bmctl.plant.plant import default_card
    >>> k = kinematics(default_card(), 300.0)
    >>> 2.0 < k.v_rms < 5.0
    True
    """
    return _kinematics_cached(card.model_dump_json(), float(rpm))


@lru_cache(maxsize=256)
def _kinematics_cached(card_json: str, rpm: float) -> Kinematics:
    card = ModelCard.model_validate_json(card_json)
    mill, mat = card.mill, card.material
    if rpm <= 0:
        return Kinematics(rpm, 0.0, 0.0, 0.0, 0.0, 0.0)
    v = ball_velocity(rpm, mill)
    theta = mat.impactor_mass_kg * v**2 / 3.0  # eqn (5) scale, mean m v^2/2 (docs/model.md)
    flight = 2 * mill.vial_radius_m - mill.ball_diameter_m  # l: mean free flight across the vial
    f = mill.ball_count * v / flight  # Sec. 2.3.1: f = Z v / l
    rb = mill.ball_diameter_m / 2
    # Maurice & Courtney: Hertz contact radius of a ball impact at velocity v
    r_h = 0.9731 * rb * (mill.ball_density_kg_m3 * v**2 / mill.ball_modulus_Pa) ** 0.2
    # share of the powder between impactor and anvil: two coated contact discs over the coated area
    trapped = card.partition.coated_fraction * 2 * math.pi * r_h**2 / coated_area(mill)
    return Kinematics(rpm, v, theta, f, trapped, r_h)
