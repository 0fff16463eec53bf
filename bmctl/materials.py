"""A small table of ball and powder materials: density, elastic modulus, Poisson ratio, yield stress.

Room-temperature handbook values for pure, annealed metals and for common grinding-ball
materials. They are typical values, not a specification: a card may state its own value
for any property (the stated value wins; :mod:`bmctl.cards` rejects one that contradicts
the table by more than its tolerance).

Sources
-------
[C] Callister & Rethwisch, *Materials Science and Engineering*, 9th ed. (2014): Table 6.1
    (elastic modulus, Poisson ratio), Table 6.2 (yield strength of annealed metals),
    Appendix B (density).
[R] CRC Handbook of Chemistry and Physics, 97th ed. (2016): molar mass, melting point.
[A] ASM Handbook Vol. 1 (1990), stainless steels (AISI 304/440C: 7.8-8.0 g/cm^3, 193-200 GPa).
[M] Grinding-ball manufacturer data (Retsch, Fritsch 2023 catalogues): tungsten carbide
    (WC-Co) 14.9 g/cm^3, zirconia (Y-TZP) 5.9-6.1 g/cm^3; moduli from Munz & Fett,
    *Ceramics* (1999): WC-6Co 620 GPa, Y-TZP 205 GPa, alumina 370 GPa.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class MaterialProps:
    """Properties of one material (SI).

    Attributes
    ----------
    name : str
        Short name used in cards (``"Al"``, ``"steel"``).
    density_kg_m3, elastic_modulus_Pa, poisson : float
        Density, Young's modulus, Poisson ratio.
    yield_stress_Pa : float or None
        Tensile yield stress of the annealed metal; None for brittle ceramics (no plastic
        yield: such a material can be a ball but not a milled powder in this model).
    molar_mass_kg_mol : float or None
        Molar mass of an element (None for alloys and compounds used only as balls).
    melting_C : float
        Melting point (decomposition or eutectic where lower).
    source : str
        Keys of the sources above.
    """

    name: str
    density_kg_m3: float
    elastic_modulus_Pa: float
    poisson: float
    yield_stress_Pa: float | None
    molar_mass_kg_mol: float | None
    melting_C: float
    source: str


MATERIALS: dict[str, MaterialProps] = {m.name: m for m in (
    # metals (powders and balls)                      rho     E        nu    sigma_y   M          T_melt
    MaterialProps("Al", 2700.0, 69e9, 0.33, 35e6, 26.982e-3, 660.3, "C, R"),
    MaterialProps("Ni", 8900.0, 207e9, 0.31, 138e6, 58.693e-3, 1455.0, "C, R"),
    MaterialProps("Cu", 8940.0, 110e9, 0.34, 69e6, 63.546e-3, 1084.6, "C, R"),
    MaterialProps("Fe", 7870.0, 207e9, 0.29, 130e6, 55.845e-3, 1538.0, "C, R"),
    MaterialProps("Ti", 4510.0, 107e9, 0.34, 450e6, 47.867e-3, 1668.0, "C, R"),
    # grinding-ball materials
    MaterialProps("steel", 7900.0, 200e9, 0.29, None, None, 1400.0, "A"),
    MaterialProps("WC", 14900.0, 620e9, 0.22, None, None, 2870.0, "M"),
    MaterialProps("ZrO2", 6050.0, 205e9, 0.31, None, None, 2715.0, "M"),
    MaterialProps("Al2O3", 3950.0, 370e9, 0.22, None, None, 2072.0, "M"),
)}


def material(name: str, where: str = "material") -> MaterialProps:
    """Look up a material by name; an unknown name raises :class:`bmctl.errors.InputError`.

    Parameters
    ----------
    name : str
        A key of :data:`MATERIALS`.
    where : str, optional
        File and field named in the error message.
    """
    from .errors import InputError

    if name not in MATERIALS:
        raise InputError(f"{where}: unknown material {name!r} (known: {', '.join(MATERIALS)}; "
                         "or state the properties in the card)")
    return MATERIALS[name]
