"""Model cards for any planetary mill and powder: derive what the user does not state, reject
what contradicts itself, report what a process engineer checks, and bound the work of a run.

A card states what a user knows -- mill geometry, ball material, diameter and count, the
ball-to-powder ratio or the powder mass, the powder's materials and molar ratio, the initial
size distribution -- and :func:`resolve_card_data` derives the rest before validation:

* ball (impactor) mass  m = rho_b pi d^3 / 6 (the paper's m = 4.14 g is a 10 mm steel ball);
* ball density and modulus from ``mill.ball_material`` (:mod:`bmctl.materials`);
* ball-to-powder ratio from ``powder.mass_kg`` (or the powder mass from the ratio);
* equivalent E and sigma by the molar law of mixtures, X = sum_i x_i X_i with molar
  fractions x_i (paper Sec. 4.1), and the powder's density as its true mixture density
  rho = sum_i x_i M_i / sum_i (x_i M_i / rho_i).

A stated value wins over a derived one, but one that contradicts it is an error: a ball mass
more than 2 % off rho_b pi d^3 / 6, a ball density or modulus more than 10 % off the named
ball material, a powder density more than 5 % off the mixture's, an E or sigma outside the
range of the powder's components (no mixture rule can leave it), a powder mass and ratio that
disagree by more than 2 %. The bonding/fracture threshold u is never derived: no per-metal
value exists; it is a calibrated constant of the powder pair (docs/own-mill.md).
"""

from __future__ import annotations

import math
import os
from typing import Any

from .errors import InputError
from .limits import BALL_TO_POWDER_RANGE

#: tables every card file must have ([material] may be left out when [powder] is given)
REQUIRED_TABLES = ("card", "process", "mill", "stochastic", "partition", "thermal", "initial", "simulation")
#: fields a card may leave out (everything else in a required table must be stated or derived)
OPTIONAL_FIELDS = {
    "card": {"description", "sources", "units"},
    "process": {"mode", "mill_min", "rest_min"},
    "mill": {"ball_material"},
    "powder": {"mass_kg"},
    "simulation": {"samplers"},
}
#: relative tolerances of the consistency checks (see the module docstring)
BALL_MASS_RTOL = 0.02
BALL_PROPERTY_RTOL = 0.10
POWDER_DENSITY_RTOL = 0.05
POWDER_MASS_RTOL = 0.02
#: sizes below which Hertzian trapping of single particles is not modelled (default validity)
S_MIN_UM_DEFAULT = 1.0


def _rel(a: float, b: float) -> float:
    return abs(a - b) / abs(b)


def _num(table: dict, key: str, where: str) -> float | None:
    """A number from a raw table, or None; strings and booleans are left for the validator."""
    v = table.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return None
    return float(v) if math.isfinite(v) and v > 0 else None


def ball_mass_kg(diameter_m: float, density_kg_m3: float) -> float:
    """Mass of one ball, rho pi d^3 / 6 (kg)."""
    return density_kg_m3 * math.pi / 6.0 * diameter_m**3


def mixture(materials: list[str], molar_ratio: list[float], where: str = "powder") -> dict[str, Any]:
    """Molar law of mixtures of the named materials (paper Sec. 4.1).

    Parameters
    ----------
    materials : list of str
        Names in :data:`bmctl.materials.MATERIALS`.
    molar_ratio : list of float
        Moles of each (any scale: 1:3 is ``[1, 3]``).
    where : str, optional
        File and table named in error messages.

    Returns
    -------
    dict
        ``elastic_modulus_Pa``, ``yield_stress_Pa``, ``poisson`` (molar averages),
        ``powder_density_kg_m3`` (true density of the mixture), ``melting_C`` (the lowest),
        ``fractions`` and the component ranges ``E_range``, ``sigma_range``.
    """
    from .materials import material

    props = [material(n, f"{where}.materials") for n in materials]
    total = sum(molar_ratio)
    x = [r / total for r in molar_ratio]
    for p in props:
        if p.yield_stress_Pa is None or p.molar_mass_kg_mol is None:
            raise InputError(f"{where}.materials: {p.name} is a ball material (no plastic yield or molar mass "
                             "in the table); state the powder's properties in [material]")
    mass = sum(xi * p.molar_mass_kg_mol for xi, p in zip(x, props))
    volume = sum(xi * p.molar_mass_kg_mol / p.density_kg_m3 for xi, p in zip(x, props))
    return {
        "fractions": x,
        "elastic_modulus_Pa": sum(xi * p.elastic_modulus_Pa for xi, p in zip(x, props)),
        "yield_stress_Pa": sum(xi * p.yield_stress_Pa for xi, p in zip(x, props)),
        "poisson": sum(xi * p.poisson for xi, p in zip(x, props)),
        "powder_density_kg_m3": mass / volume,
        "melting_C": min(p.melting_C for p in props),
        "melting_of": min(props, key=lambda p: p.melting_C).name,
        "E_range": (min(p.elastic_modulus_Pa for p in props), max(p.elastic_modulus_Pa for p in props)),
        "sigma_range": (min(p.yield_stress_Pa for p in props), max(p.yield_stress_Pa for p in props)),
    }


def _fill_or_check(table: dict, key: str, derived: float, rtol: float, where: str, why: str) -> None:
    stated = _num(table, key, where)
    if key not in table:
        table[key] = derived
    elif stated is not None and _rel(stated, derived) > rtol:
        raise InputError(f"{where}.{key}: {stated:g} contradicts {why} = {derived:.4g} "
                         f"(more than {rtol:.0%} apart); correct it or leave it out to derive it")


#: the stated fields the derivations read, checked (type and range) before anything is derived
DERIVATION_INPUTS = {
    "mill": ("ball_diameter_m", "ball_count", "ball_density_kg_m3", "ball_modulus_Pa"),
    "material": ("impactor_mass_kg",),
    "powder": ("mass_kg",),
}
#: fields a card may leave out when what derives them is stated, in the order they are derived,
#: with what derives them (named when neither is there)
DERIVED_FROM = {
    ("mill", "ball_density_kg_m3"): "mill.ball_material",
    ("mill", "ball_modulus_Pa"): "mill.ball_material",
    ("material", "impactor_mass_kg"): "mill.ball_diameter_m with the ball's density",
    ("material", "elastic_modulus_Pa"): "[powder] materials and molar_ratio",
    ("material", "yield_stress_Pa"): "[powder] materials and molar_ratio",
    ("material", "powder_density_kg_m3"): "[powder] materials and molar_ratio",
    ("mill", "ball_to_powder_ratio"): "powder.mass_kg with the balls' count and mass",
}


def _check_derivation_inputs(d: dict[str, Any], source: str) -> None:
    """Refuse a stated input of a derivation that is not a number in its range, naming that field.

    Without this a ball diameter stated in mm (``ball_diameter_m = 20``) is refused as the
    ball-to-powder ratio it implies, and ``ball_count = "8"`` as a missing ratio.
    """
    from pydantic import ValidationError

    from .config import Material, Mill, Powder, _fmt_loc, quote

    for name, model in (("mill", Mill), ("material", Material), ("powder", Powder)):
        table = d.get(name)
        if not isinstance(table, dict):
            continue
        try:
            model.model_validate(table)
        except ValidationError as exc:
            for e in exc.errors():
                if e["type"] != "missing" and e["loc"] and e["loc"][0] in DERIVATION_INPUTS[name]:
                    msg = e["msg"].removeprefix("Value error, ")
                    if "input" in e and not isinstance(e["input"], (dict, list)) and "got" not in msg:
                        msg += f" (got {quote(e['input'])})"
                    raise InputError(f"{source}: {_fmt_loc((name,) + tuple(e['loc']))}: {msg}") from None


def check_unknown_keys(d: dict[str, Any], source: str) -> None:
    """Refuse a table or field a card does not have, naming the known one it likely mistypes.

    Checked before anything is reported missing: ``alpah = 2.1`` is one typo, not a missing
    ``alpha``. Known tables and fields left out are the first candidates of the hint.

    Parameters
    ----------
    d : dict
        The card's parsed TOML (top-level keys and tables).
    source : str
        The file, named in error messages.

    Raises
    ------
    InputError
        ``card.toml: stochastic.alpah: unknown field (did you mean alpha?)`` or
        ``card.toml: [stochastik]: unknown table (did you mean [stochastic]?)``.
    """
    from .config import ModelCard, _fmt_loc, fields_at, unknown_key_message

    tables = set(ModelCard.model_fields)
    for key, value in d.items():
        if key not in tables:
            is_table = isinstance(value, dict)
            where = f"[{_fmt_loc((key,))}]" if is_table else _fmt_loc((key,))
            msg = unknown_key_message(key, tables, table=is_table, likely=tables - set(d))
            raise InputError(f"{source}: {where}: {msg}")
    for name, table in d.items():
        known = fields_at(ModelCard, (name,))
        for key in table if isinstance(table, dict) else ():
            if key not in known:
                msg = unknown_key_message(key, known, likely=known - set(table))
                raise InputError(f"{source}: {_fmt_loc((name, key))}: {msg}")


def resolve_card_data(data: dict[str, Any], source: str) -> dict[str, Any]:
    """Complete a card's raw TOML tables: check they are all there, derive what is not stated,
    reject contradictions. Returns a new dict ready for :class:`bmctl.config.ModelCard`.

    Parameters
    ----------
    data : dict
        The parsed TOML.
    source : str
        The file, named in error messages.

    Raises
    ------
    InputError
        A missing table or field, or contradictory values (one line naming the field).
    """
    from .config import ModelCard

    d = {k: (dict(v) if isinstance(v, dict) else v) for k, v in data.items()}
    tables = REQUIRED_TABLES + (() if "powder" in d else ("material",))
    check_unknown_keys(d, source)
    for name in tables:
        if name not in d:
            raise InputError(f"{source}: [{name}]: required table is missing")
        if not isinstance(d[name], dict):
            raise InputError(f"{source}: {name}: expected a table")
    for name in ("powder", "validity", "material"):
        if name in d and not isinstance(d[name], dict):
            raise InputError(f"{source}: {name}: expected a table")
    _check_derivation_inputs(d, source)
    mill, mat = d["mill"], d.setdefault("material", {})
    # the ball: density and modulus from its material
    if isinstance(mill.get("ball_material"), str):
        from .materials import material

        ball = material(mill["ball_material"], f"{source}: mill.ball_material")
        why = f"the table's {ball.name}"
        _fill_or_check(mill, "ball_density_kg_m3", ball.density_kg_m3, BALL_PROPERTY_RTOL, f"{source}: mill", why)
        _fill_or_check(mill, "ball_modulus_Pa", ball.elastic_modulus_Pa, BALL_PROPERTY_RTOL, f"{source}: mill", why)
    d_b, rho_b = _num(mill, "ball_diameter_m", ""), _num(mill, "ball_density_kg_m3", "")
    if d_b is not None and rho_b is not None:
        _fill_or_check(mat, "impactor_mass_kg", ball_mass_kg(d_b, rho_b), BALL_MASS_RTOL, f"{source}: material",
                       f"a {d_b * 1e3:g} mm ball of {rho_b:g} kg/m^3: rho pi d^3/6")
    # the powder: law of mixtures, and its mass
    powder = d.get("powder")
    if isinstance(powder, dict):
        names, ratio = powder.get("materials"), powder.get("molar_ratio")
        ok = (isinstance(names, list) and isinstance(ratio, list) and len(names) == len(ratio) > 0
              and all(isinstance(n, str) for n in names)
              and all(isinstance(r, (int, float)) and not isinstance(r, bool) and math.isfinite(r) and r > 0
                      for r in ratio))
        if ok:
            mix = mixture(names, [float(r) for r in ratio], f"{source}: powder")
            where = f"{source}: material"
            _fill_or_check(mat, "powder_density_kg_m3", mix["powder_density_kg_m3"], POWDER_DENSITY_RTOL, where,
                           "the mixture's density")
            for key, rng in (("elastic_modulus_Pa", mix["E_range"]), ("yield_stress_Pa", mix["sigma_range"])):
                stated = _num(mat, key, where)
                if key not in mat:
                    mat[key] = mix[key]
                elif stated is not None and not (rng[0] * 0.99 <= stated <= rng[1] * 1.01):
                    raise InputError(f"{where}.{key}: {stated:g} lies outside the range of the powder's "
                                     f"materials [{rng[0]:g}, {rng[1]:g}]: no law of mixtures gives it")
        n_b = mill.get("ball_count")
        m_p, m_b = _num(powder, "mass_kg", ""), _num(mat, "impactor_mass_kg", "")
        if m_p is not None and m_b is not None and isinstance(n_b, int) and not isinstance(n_b, bool) and n_b > 0:
            why = f"{n_b} balls of {m_b * 1e3:.4g} g over powder.mass_kg {m_p:g}"
            lo, hi = BALL_TO_POWDER_RANGE
            if "ball_to_powder_ratio" not in mill and not lo <= n_b * m_b / m_p <= hi:
                raise InputError(f"{source}: mill.ball_count, powder.mass_kg: {why} give a ball-to-powder ratio of "
                                 f"{n_b * m_b / m_p:.4g}, outside {lo:g}-{hi:g} (mechanical alloying uses 1:1 to "
                                 "100:1); check both")
            _fill_or_check(mill, "ball_to_powder_ratio", n_b * m_b / m_p, POWDER_MASS_RTOL, f"{source}: mill", why)
    # completeness: every field that has a meaning is stated or derived; a derivable one is named
    # last, with what derives it (a card without mill.ball_material lacks the ball's density first,
    # not the ball-to-powder ratio that would follow from it)
    missing = []
    for name in tables + tuple(t for t in ("powder", "validity") if t in d):
        model = ModelCard.model_fields[name].annotation
        model = next((a for a in getattr(model, "__args__", (model,)) if a is not type(None)), model)
        optional = OPTIONAL_FIELDS.get(name, set()) | (set(model.model_fields) if name == "validity" else set())
        missing += [(name, f) for f in model.model_fields if f not in optional and f not in d[name]]
    if missing:
        order = list(DERIVED_FROM)
        name, field = min(missing, key=lambda nf: order.index(nf) + 1 if nf in DERIVED_FROM else 0)
        hint = f" (state it, or {DERIVED_FROM[name, field]} to derive it)" if (name, field) in DERIVED_FROM else ""
        raise InputError(f"{source}: {name}.{field}: required field is missing{hint}")
    return d


# --- validity ------------------------------------------------------------------------------------

def size_range(card) -> tuple[float, float]:
    """``(s_min_um, s_max_um)`` where ``card`` holds: ``[validity]``'s, else 1 µm and ``simulation.s_max_um``."""
    v = card.validity
    return (v.s_min_um if v.s_min_um is not None else S_MIN_UM_DEFAULT,
            v.s_max_um if v.s_max_um is not None else card.simulation.s_max_um)


def validity(card) -> dict[str, Any]:
    """The range where ``card`` holds, with the reason of each limit.

    Returns
    -------
    dict
        ``rpm_max``, ``s_min_um``, ``s_max_um``, ``temperature_max_C`` (None if unknown) and
        ``temperature_reason``.
    """
    v = card.validity
    t_max, reason = v.temperature_max_C, "stated in [validity]"
    if t_max is None and card.powder is not None:
        mix = mixture(card.powder.materials, card.powder.molar_ratio)
        t_max, reason = mix["melting_C"], f"melting point of {mix['melting_of']}"
    s_min, s_max = size_range(card)
    return {
        "rpm_max": min(v.rpm_max or card.mill.rpm_max, card.mill.rpm_max),
        "s_min_um": s_min,
        "s_max_um": s_max,
        "temperature_max_C": t_max,
        "temperature_reason": reason,
    }


def run_warnings(card, t_h, temperature_c, s_mean_um) -> list[str]:
    """Warnings for a run that left the card's validity range (one line each).

    Parameters
    ----------
    card : ModelCard
    t_h, temperature_c, s_mean_um : sequences of float
        Recorded times, vial temperatures and mean sizes.
    """
    val = validity(card)
    out = []
    t_max = val["temperature_max_C"]
    hot = [(t, T) for t, T in zip(t_h, temperature_c) if t_max is not None and T > t_max]
    if hot:
        t, T = max(hot, key=lambda x: x[1])
        out.append(f"{card.card.name}: vial temperature {T:.0f} °C at {t:g} h is above the card's maximum "
                   f"{t_max:g} °C ({val['temperature_reason']}): the model does not hold there")
    for t, s in zip(t_h, s_mean_um):
        if not (val["s_min_um"] <= s <= val["s_max_um"]):
            out.append(f"{card.card.name}: mean size {s:.3g} µm at {t:g} h is outside the card's "
                       f"[{val['s_min_um']:g}, {val['s_max_um']:g}] µm")
            break
    return out


# --- the report of `bmctl card show` -------------------------------------------------------------

def report_rpms(card) -> list[float]:
    """The speeds of the report: the card's rpm x 0.5, 0.75, 1, 1.25, and rpm_max (distinct, <= rpm_max)."""
    base = card.process.rpm or card.mill.rpm_max / 2
    rpms = {round(base * f) for f in (0.5, 0.75, 1.0, 1.25)} | {round(card.mill.rpm_max)}
    return sorted(r for r in rpms if 0 < r <= card.mill.rpm_max)


def card_report(card, rpms: list[float] | None = None, coeff_window: dict | None = None) -> dict[str, Any]:
    """Derived quantities a process engineer checks, per rpm, and the card's validity range.

    Parameters
    ----------
    card : ModelCard
    rpms : list of float, optional
        Sun-disc speeds (default :func:`report_rpms`).
    coeff_window : dict, optional
        ``[window]`` of the card's moment coefficients (:class:`bmctl.moments.coeffs.CoeffFile`).

    Returns
    -------
    dict
        ``loading`` (ball and powder masses, fill), ``powder`` (composition and the law of
        mixtures beside the stated values), ``rows`` (one dict per rpm: ``rpm``, ``v_ms``
        ball velocity (Burgio), ``collisions_per_s`` f = Z v / l, ``impact_energy_mJ`` mean
        m v^2 / 2, ``hertz_radius_um``, ``trapped_share``, ``hits_per_particle_per_h``,
        ``power_W`` dissipated, ``steady_temperature_C`` = T_amb + P tau / C, ``valid``,
        ``in_window``: the steady temperature lies in :func:`operating_window`, within
        :data:`WINDOW_SLACK_K` as :func:`window_warnings` allows), ``validity`` and
        ``window`` (:func:`operating_window`).
    """
    from .moments.physics import plant_hit_rate  # lazy: the kinematics' home may move
    from .plant.kinematics import kinematics

    mill, mat, th = card.mill, card.material, card.thermal
    balls_kg = mill.ball_count * mat.impactor_mass_kg
    vial_m3 = math.pi * mill.vial_radius_m**2 * mill.vial_height_m
    loading = {
        "ball_mass_g": mat.impactor_mass_kg * 1e3,
        "ball_mass_from_geometry_g": ball_mass_kg(mill.ball_diameter_m, mill.ball_density_kg_m3) * 1e3,
        "balls_total_g": balls_kg * 1e3,
        "powder_g": balls_kg / mill.ball_to_powder_ratio * 1e3,
        "ball_to_powder_ratio": mill.ball_to_powder_ratio,
        "vial_ml": vial_m3 * 1e6,
        "ball_fill": mill.ball_count * math.pi / 6 * mill.ball_diameter_m**3 / vial_m3,
    }
    powder = None
    if card.powder is not None:
        mix = mixture(card.powder.materials, card.powder.molar_ratio)
        powder = {
            "materials": list(card.powder.materials),
            "molar_fractions": mix["fractions"],
            "E_GPa": (mat.elastic_modulus_Pa / 1e9, mix["elastic_modulus_Pa"] / 1e9),
            "sigma_MPa": (mat.yield_stress_Pa / 1e6, mix["yield_stress_Pa"] / 1e6),
            "density_kg_m3": (mat.powder_density_kg_m3, mix["powder_density_kg_m3"]),
            "poisson": mix["poisson"],
        }
    val = validity(card)
    win = operating_window(card, coeff_window)
    lo, hi = win["temperature_c"] or (-math.inf, math.inf)
    rows = []
    for rpm in rpms or report_rpms(card):
        k = kinematics(card, float(rpm))
        power = k.mean_power_W
        t_ss = th.ambient_C + power * th.cooling_time_s / th.heat_capacity_J_per_K
        rows.append({
            "rpm": float(rpm),
            "v_ms": k.v_rms,
            "collisions_per_s": k.frequency,
            "impact_energy_mJ": 1.5 * k.energy_scale * 1e3,  # mean of Gamma(3/2, theta), eqn (5)
            "hertz_radius_um": k.contact_radius * 1e6,
            "trapped_share": k.trapped_fraction,
            "hits_per_particle_per_h": plant_hit_rate(card, k) * 3600.0,
            "power_W": power,
            "steady_temperature_C": t_ss,
            "valid": rpm <= val["rpm_max"] and (val["temperature_max_C"] is None or t_ss <= val["temperature_max_C"]),
            # with the slack the run's warning allows (window_warnings): the card's own calibration speeds are in
            "in_window": lo - WINDOW_SLACK_K <= t_ss <= hi + WINDOW_SLACK_K,
        })
    return {"name": card.card.name, "loading": loading, "powder": powder, "rows": rows, "validity": val,
            "window": win}


# --- bounded work --------------------------------------------------------------------------------

#: plant throughput used to turn work into time: particle impacts per CPU second and CPU seconds
#: per time step, measured on this project's machine (fan card: 400 rpm, 20,000 particles, 1 h:
#: 2.8e5 impacts, 551 steps in 0.81 s; 300 rpm, 5,000 particles, 2 h: 8.2e4 impacts, 657 steps
#: in 0.50 s; a 100 h rest: 6,000 steps in 0.21 s) and rounded towards the slow side
IMPACTS_PER_CPU_S = 2e5
STEP_CPU_S = 3e-4
#: bytes per recorded raster bin (float64 record + float32 output copy) and per simulated particle
RASTER_BYTES_PER_BIN = 12
PARTICLE_BYTES = 200


from .work import budget, check_work  # noqa: E402,F401 - the budget and the check live in bmctl.work


def simulation_work(card, segments, particles: int, every_h: float, raster: bool = True) -> dict[str, float]:
    """Estimated work of a plant run: impacts, time steps, records, CPU seconds and memory.

    Parameters
    ----------
    card : ModelCard
    segments : sequence of (hours, rpm)
    particles : int
        Simulated particles M.
    every_h : float
        Recording interval.
    raster : bool, optional
        Whether each record keeps the population raster (``bmctl simulate``) or moments only.
    """
    from .moments.physics import plant_hit_rate
    from .plant.kinematics import kinematics

    sim = card.simulation
    impacts = steps = 0.0
    for hours, rpm in segments:
        seconds = hours * 3600.0
        rate = plant_hit_rate(card, kinematics(card, float(rpm))) if rpm > 0 else 0.0
        dt = min(sim.max_step_s, sim.batch_fraction / rate) if rate > 0 else sim.max_step_s
        impacts += rate * particles * seconds / 2.0
        steps += seconds / dt
    total_h = sum(h for h, _ in segments)
    records = total_h / every_h + len(segments) + 1
    bins = (sim.s_max_um / 1.0) * 100 if raster else 10  # DS_UM = 1 um, DR = 0.01
    return {
        "impacts": impacts,
        "steps": steps,
        "records": records,
        "cpu_s": impacts / IMPACTS_PER_CPU_S + steps * STEP_CPU_S,
        "memory_bytes": records * bins * RASTER_BYTES_PER_BIN + particles * PARTICLE_BYTES,
    }


def design_work(hours: float, interval_h: float, sweep=(1.0,)) -> dict[str, float]:
    """Estimated work of ``bmctl design``: the global search over operable schedules and the local NLP
    over a batch of ``hours`` in K = ceil(hours / interval_h) control intervals, once per batch length
    of the sweep (``min_time`` / ``min_energy``: each fraction of ``hours``; ``target``: ``(1.0,)``).

    Both grow with the batch length in proportion, hardly with K: the search's candidates are about as
    many at any interval, the NLP integrates on a grid of at most 0.5 h, and the memory is the search's
    states over the batch. Measured on this project's machine (2 cores at load 1-2, ``nice``, the whole
    command with ``--plant-seeds 0`` on the lab card, targets s_mean_um=30, s_mean_um=400 and d50_um=45),
    CPU s: 4 h 1.8-3.5 at 0.25, 0.5 and 1 h intervals; 12 h 5.9-8.9; 24 h 13-18; 48 h 26-31; 72 h 67
    (0.25 h), 53 (0.5 h), 52 (1 h), 58 (2 h), 57 (6 h); 200 h 148 (0.5 h); 24 h at 1-min intervals 43
    (K = 1440), 12 h and 48 h at 0.02 h 19 and 75; ``--objective min_time`` (the sweep 1/4, 1/2, 3/4, 1)
    12 h 18 and 24 h 36. Peak memory: 12 h 0.52 GB, 24 h 0.79 GB, 72 h 2.9 GB, 200 h 6.0 GB;
    min_time 24 h 1.8 GB. The constants below put each CPU time 1.2-3 times under the estimate and
    each peak memory 1.1-1.7 times. The old model (1.5 CPU s per interval, in proportion to K^2
    beyond 24 intervals) put 72 h at 0.25 h at 5200 CPU s, and its dense KKT block at 53 MB.

    Parameters
    ----------
    hours : float
        Batch length.
    interval_h : float
        The controller's interval.
    sweep : sequence of float, optional
        Fractions of ``hours`` designed one after another (the controller's ``[objective] sweep`` for
        min_time and min_energy).

    Examples
    --------
    >>> round(design_work(72.0, 0.25)["cpu_s"])  # measured: 67 CPU s
    85
    """
    hours = min(max(0.0, float(hours)), 1e15)
    fracs = [min(max(float(f), 0.0), 1.0) for f in sweep] or [1.0]
    cpu, batch_h = DESIGN_CPU_S, 0.0
    for f in fracs:
        k = max(1.0, float(math.ceil(min(hours * f / interval_h, 1e15) - 1e-9)))
        cpu += DESIGN_CPU_S_PER_H * hours * f + DESIGN_CPU_S_PER_INTERVAL * k
        batch_h += hours * f
    k = max(1.0, float(math.ceil(min(hours / interval_h, 1e15) - 1e-9)))
    return {"intervals": k, "cpu_s": cpu, "memory_bytes": DESIGN_BYTES + DESIGN_BYTES_PER_H * batch_h}


#: ``design``'s CPU seconds (the command's start included), per batch hour designed and per control
#: interval, and its memory and memory per batch hour designed (measured numbers: :func:`design_work`)
DESIGN_CPU_S = 0.5
DESIGN_CPU_S_PER_H = 1.1
DESIGN_CPU_S_PER_INTERVAL = 0.02
DESIGN_BYTES = 4e8
DESIGN_BYTES_PER_H = 4e7


def identify_work(card, specs_seeds: list[tuple[list, int]], particles: int, dt_h: float) -> dict[str, float]:
    """Estimated plant work of ``bmctl identify``: every experiment on every seed.

    Parameters
    ----------
    card : ModelCard
    specs_seeds : list of (specs, number of seeds)
        Experiment designs (:class:`bmctl.moments.identify.Spec`) and how many seeds run each.
    particles : int
        Simulated particles per plant.
    dt_h : float
        Length of one (rpm, milling) interval of a spec.
    """
    total = {"impacts": 0.0, "steps": 0.0, "records": 0.0, "cpu_s": 0.0, "memory_bytes": 0.0}
    for specs, seeds in specs_seeds:
        for spec in specs:
            segs = []
            for rpm, duty in list(spec.prefix) + list(spec.inputs):
                segs += [(dt_h * duty, rpm), (dt_h * (1.0 - duty), 0.0)]
            w = simulation_work(card, [s for s in segs if s[0] > 0] or [(dt_h, 0.0)], particles, dt_h, raster=False)
            for k in ("impacts", "steps", "records", "cpu_s"):
                total[k] += seeds * w[k]
            total["memory_bytes"] = max(total["memory_bytes"], w["memory_bytes"])
    return total


# --- the vial's temperature ------------------------------------------------------------------------

#: the highest vial temperature any card may reach when it names no powder (tungsten melts at 3422 C)
TEMPERATURE_CEILING_C = 3500.0


def melting_limit(card) -> tuple[float, str]:
    """The temperature no run may reach: the powder's lowest melting point, else the card's
    stated ``validity.temperature_max_C``, else :data:`TEMPERATURE_CEILING_C`; with the reason."""
    if card.powder is not None:
        mix = mixture(card.powder.materials, card.powder.molar_ratio)
        return mix["melting_C"], f"the melting point of {mix['melting_of']}"
    if card.validity.temperature_max_C is not None:
        return card.validity.temperature_max_C, "the card's validity.temperature_max_C"
    return TEMPERATURE_CEILING_C, "the highest melting point of any powder bmctl models"


def peak_temperature_c(card, segments) -> tuple[float, float]:
    """Peak vial temperature of a (hours, rpm) schedule from the card's ambient, and when (h).

    The plant heats the vial by the mean dissipated power of its speed (first-order model,
    docs/model.md Sec. 4): T_ss = T_amb + P tau / C and T(t) = T_ss + (T_0 - T_ss) exp(-t / tau)
    within a segment, so the peak lies at a segment's end and is known before any run.

    Parameters
    ----------
    card : ModelCard
    segments : sequence of (hours, rpm)
    """
    from .plant.kinematics import kinematics

    th = card.thermal
    T = peak = th.ambient_C
    t = at = 0.0
    power = {}
    for hours, rpm in segments:
        if rpm not in power:
            power[rpm] = kinematics(card, float(rpm)).mean_power_W if rpm > 0 else 0.0
        t_ss = th.ambient_C + power[rpm] * th.cooling_time_s / th.heat_capacity_J_per_K
        T = t_ss + (T - t_ss) * math.exp(-hours * 3600.0 / th.cooling_time_s)
        t += hours
        if T > peak:
            peak, at = T, t
    return peak, at


def check_melting(card, segments, where: str) -> float:
    """Refuse a schedule that would heat the vial above :func:`melting_limit` (one line naming
    ``where``, the peak and the limit); returns the peak temperature.

    Parameters
    ----------
    card : ModelCard
    segments : sequence of (hours, rpm)
    where : str
        The file or flags that set the schedule.
    """
    peak, at = peak_temperature_c(card, segments)
    limit, reason = melting_limit(card)
    if not peak <= limit:
        raise InputError(f"{where}: the vial would reach {peak:.0f} °C at {at:g} h, above {limit:g} °C "
                         f"({reason}; {card.card.name}): no model holds there; lower the rpm or add rests")
    return peak


# --- the fingerprint the moment coefficients are tied to ------------------------------------------

#: card tables whose every field the moment model's coefficients depend on: what the plant experiments of
#: ``bmctl identify`` and the model's card-derived constants read (docs/moments.md, Sec. 6). Left out:
#: [card] (names), [process] (the recipe: the model holds for any schedule), [powder] (its composition
#: reaches the model only through the [material] values it resolves to, which are in), [validity],
#: [simulation] (the plant's particle count, recording and step control; same laws) and
#: ``mill.ball_material`` (a name; the density and modulus it resolves to are in).
FINGERPRINT_TABLES = ("mill", "material", "stochastic", "partition", "thermal", "initial")
FINGERPRINT_SKIP = frozenset({"mill.ball_material"})


def fingerprint_values(card) -> dict[str, float]:
    """The card fields the moment model depends on, as ``{"table.field": value}`` (sorted).

    Parameters
    ----------
    card : ModelCard
        A validated card (derived fields already filled in).

    Returns
    -------
    dict
        Numbers only (ints stay ints), keyed by dotted field name.

    Examples
    --------
    >>> from bmctl.config import load_card
    >>> v = fingerprint_values(load_card("models/alni-1to1-300rpm-lab.toml"))
    >>> v["mill.ball_diameter_m"], v["stochastic.gamma_per_um2"]
    (0.01, 0.000182)
    >>> "process.rpm" in v
    False
    """
    out: dict[str, float] = {}
    for table in FINGERPRINT_TABLES:
        for field, v in getattr(card, table).model_dump().items():
            key = f"{table}.{field}"
            if key in FINGERPRINT_SKIP or v is None:
                continue
            out[key] = v if isinstance(v, int) and not isinstance(v, bool) else float(v)
    return dict(sorted(out.items()))


def fingerprint(values: dict[str, float]) -> str:
    """``sha256:<16 hex>`` of fingerprint values (:func:`fingerprint_values`): a short name to compare by eye.

    Parameters
    ----------
    values : dict
        ``{"table.field": number}``.

    Examples
    --------
    >>> fingerprint({"mill.ball_count": 10}) == fingerprint({"mill.ball_count": 10.0})
    True
    """
    import hashlib

    text = "\n".join(f"{k}={float(v)!r}" for k, v in sorted(values.items()))
    return "sha256:" + hashlib.sha256(text.encode()).hexdigest()[:16]


#: relative tolerance of a fingerprint field (TOML keeps floats exactly; this absorbs a hand-typed 1e-4 vs 0.0001)
FINGERPRINT_RTOL = 1e-9


def fingerprint_diff(card_values: dict, recorded: dict) -> list[str]:
    """The fields where a card and a coefficient file's recorded fingerprint differ, as
    ``"table.field <card value> (coefficients: <recorded>)"``; empty when they match.

    Parameters
    ----------
    card_values : dict
        :func:`fingerprint_values` of the card in use.
    recorded : dict
        The values the coefficient file recorded.

    Examples
    --------
    >>> fingerprint_diff({"a.x": 1.0, "a.y": 2.0}, {"a.x": 1.0, "a.y": 3.0})
    ['a.y 2 (coefficients: 3)']
    >>> fingerprint_diff({"a.x": 1.0}, {"a.x": 1.0})
    []
    """
    out = []
    for k in sorted(set(card_values) | set(recorded)):
        a, b = card_values.get(k), recorded.get(k)
        if a is None or b is None:
            out.append(f"{k} {'-' if a is None else f'{a:g}'} (coefficients: {'-' if b is None else f'{b:g}'})")
        elif not math.isclose(float(a), float(b), rel_tol=FINGERPRINT_RTOL, abs_tol=0.0):
            out.append(f"{k} {a:g} (coefficients: {b:g})")
    return out


# --- the operating window: where the model was calibrated ------------------------------------------

def steady_temperature_c(card, rpm: float) -> float:
    """Steady vial temperature at ``rpm`` (°C): T_ss = T_amb + P(rpm) tau / C (docs/model.md Sec. 4).

    Parameters
    ----------
    card : ModelCard
    rpm : float
        Sun-disc speed; 0 is a rest (ambient).

    Examples
    --------
    >>> from bmctl.config import load_card
    >>> round(steady_temperature_c(load_card("models/alni-1to1-300rpm-lab.toml"), 300.0), 1)
    65.5
    """
    from .plant.kinematics import kinematics

    th = card.thermal
    power = kinematics(card, float(rpm)).mean_power_W if rpm > 0 else 0.0
    return th.ambient_C + power * th.cooling_time_s / th.heat_capacity_J_per_K


def operating_window(card, coeff_window: dict | None = None) -> dict[str, Any]:
    """The steady vial temperatures the model was calibrated for, and where that is written down.

    Two ranges meet here: the card's ``validity.calibrated_temperature_max_C`` (the hottest steady
    vial of the data its constants were calibrated on; from the ambient up) and the coefficient file's
    ``[window] temperature_c`` (the steady vial temperatures of the identification's plant experiments,
    :func:`bmctl.moments.identify.design_window`). The window is their intersection.

    Parameters
    ----------
    card : ModelCard
    coeff_window : dict, optional
        ``CoeffFile.window`` of the coefficients in use.

    Returns
    -------
    dict
        ``temperature_c`` (low, high) or None when nothing bounds it, and ``why`` (where each bound comes from).
    """
    lo, hi, why = -math.inf, math.inf, []
    cal = card.validity.calibrated_temperature_max_C
    if cal is not None:
        lo, hi = card.thermal.ambient_C, float(cal)
        why.append("the card's validity.calibrated_temperature_max_C")
    win = (coeff_window or {}).get("temperature_c")
    if win is not None:
        lo, hi = max(lo, win[0]), min(hi, win[1])
        why.append("the identification's [window]")
    if not why:
        return {"temperature_c": None, "why": ""}
    return {"temperature_c": (lo, hi), "why": " and ".join(why)}


#: a steady vial temperature this close to the window's ends counts as inside it: the card states its
#: calibrated maximum to 0.1 °C (the 400 rpm steady vial of the calibration runs), so the very speeds it was
#: calibrated at must not warn by a rounding
WINDOW_SLACK_K = 0.5


def window_warnings(card, rpms, coeff_window: dict | None = None) -> list[str]:
    """One warning line when the steady vial temperature at a milling speed in use leaves
    :func:`operating_window` (the hottest or coldest offender is named), and one before it when a
    speed is above the card's ``validity.rpm_max``; empty otherwise.

    Parameters
    ----------
    card : ModelCard
    rpms : iterable of float
        The speeds the run mills at (0, a rest, is skipped).
    coeff_window : dict, optional
        ``CoeffFile.window`` of the coefficients in use.

    Examples
    --------
    >>> from bmctl.config import load_card
    >>> card = load_card("models/alni-1to1-300rpm-lab.toml")
    >>> window_warnings(card, [300.0])
    []
    >>> print(window_warnings(card, [300.0, 500.0])[0])  # doctest: +NORMALIZE_WHITESPACE
    alni-1to1-300rpm-lab: steady vial temperature 213 °C at 500 rpm is outside 25–121.1 °C, the range the model
    was calibrated for (the card's validity.calibrated_temperature_max_C): its predictions at that speed are
    extrapolations, also in bursts that keep the vial cooler
    >>> window_warnings(card, [400.0])  # the calibration's own 400 rpm: within WINDOW_SLACK_K of the maximum
    []
    """
    rpms = [float(r) for r in rpms]
    lines = []
    v_rpm = card.validity.rpm_max
    fast = max((r for r in rpms if r > 0), default=0.0)
    if v_rpm is not None and fast > v_rpm:  # the card's own statement of where it holds
        lines.append(f"{card.card.name}: {fast:g} rpm is above the card's validity.rpm_max ({v_rpm:g} rpm), where "
                     "it holds: its predictions at that speed are extrapolations")
    win = operating_window(card, coeff_window)
    if win["temperature_c"] is None:
        return lines
    lo, hi = win["temperature_c"]
    temps = {r: steady_temperature_c(card, r) for r in set(rpms) if r > 0}
    out = [(T, r) for r, T in temps.items() if not lo - WINDOW_SLACK_K <= T <= hi + WINDOW_SLACK_K]
    if not out:
        return lines
    T, r = max(out, key=lambda tr: max(tr[0] - hi, lo - tr[0]))
    # as many decimals as it takes for a temperature just past the range not to print as its end
    d = next((k for k in range(3) if round(T, k) not in (round(lo, k), round(hi, k))), 3)
    return lines + [f"{card.card.name}: steady vial temperature {T:.{d}f} °C at {r:g} rpm is outside {lo:g}–{hi:g} "
                    f"°C, the range the model was calibrated for ({win['why']}): its predictions at that speed are "
                    "extrapolations, also in bursts that keep the vial cooler"]


def simulation_warnings(card, segments, t_h, temperature_c, s_mean_um, size_t_h=None) -> list[str]:
    """Every warning ``simulate`` gives for a run (one line each): the vial above the card's maximum
    and a mean size outside its range (:func:`run_warnings`), then a milling speed outside the
    calibrated window (:func:`window_warnings`).

    Parameters
    ----------
    card : ModelCard
    segments : sequence of (hours, rpm)
        The schedule the run mills.
    t_h, temperature_c, s_mean_um : sequences of float
        Recorded times, vial temperatures and mean sizes.
    size_t_h : sequence of float, optional
        The times of ``s_mean_um`` where they are not ``t_h`` (``compare`` takes the peak temperature
        and the size at different times).

    Returns
    -------
    list of str

    Examples
    --------
    >>> from bmctl.config import load_card
    >>> card = load_card("models/alni-1to1-300rpm-lab.toml")
    >>> simulation_warnings(card, [(2.0, 300.0)], [0.0, 2.0], [25.0, 60.0], [50.0, 40.0])
    []
    >>> for line in simulation_warnings(card, [(1.0, 0.0), (2.0, 600.0)], [3.0], [700.0], [0.5], size_t_h=[2.0]):
    ...     print(line)  # doctest: +NORMALIZE_WHITESPACE
    alni-1to1-300rpm-lab: vial temperature 700 °C at 3 h is above the card's maximum 660.3 °C (melting point
    of Al): the model does not hold there
    alni-1to1-300rpm-lab: mean size 0.5 µm at 2 h is outside the card's [1, 1000] µm
    alni-1to1-300rpm-lab: steady vial temperature 349 °C at 600 rpm is outside 25–121.1 °C, the range the model
    was calibrated for (the card's validity.calibrated_temperature_max_C): its predictions at that speed are
    extrapolations, also in bursts that keep the vial cooler
    """
    return (run_warnings(card, t_h, temperature_c, [])
            + run_warnings(card, t_h if size_t_h is None else size_t_h, [], s_mean_um)
            + window_warnings(card, [rpm for _, rpm in segments]))
