"""Closed-loop campaigns on hidden mills: a scripted operator accepts every advice through the CLI.

    nice python benchmarks/hidden_mills.py [--cases A,B,...] [--particles 5000] [--out out/RESULTS_NAME]
    nice python benchmarks/hidden_mills.py --cases H,I,J,K,L --results-name hidden_mills_heldout   # held out
    nice python benchmarks/hidden_mills.py --sample-particles 1000 --results-name NAME   # larger samples
    nice python benchmarks/hidden_mills.py --sample-on-request --results-name NAME   # extra samples when asked
    nice python benchmarks/hidden_mills.py --sample-feed --results-name NAME   # the feed sampled at 0 h too
    nice python benchmarks/hidden_mills.py --card models/OTHER.toml --mills FILE --results-name NAME   # another card
    nice python benchmarks/hidden_mills.py --mills benchmarks/mills-unseen.toml --results-name hidden_mills_unseen

Each case is a plant built from the laboratory card with gamma and delta multiplied (0.6-1.6) and one
more card field changed (powder mass through the ball-to-powder ratio, the ball count or the ball
size). The campaign is given only the card. Mills A-G are the ones the controller was developed
on; H-L (:data:`HELD_OUT`) were drawn afterwards and never used to choose a setting; ``--mills``
runs mills of your own from a TOML file (:func:`load_mills`; ``benchmarks/mills-unseen.toml``
holds seven, M-S, drawn after the controller was final). Per case:

1. **A reachable target.** A plain-schedule sweep on the hidden plant (one rpm held for the whole
   batch, 100-460 rpm in 20 rpm steps, and the paper's 30 min on / 10 min off at 400-500 rpm):
   the target is the final mean size of the case's reference schedule (its rpm, or the fastest
   one under the ceiling less 3 °C), so a plain schedule reaches it on the hidden mill.
2. **The best plain schedule chosen without the hidden mill.** The same sweep on the card's plant;
   the schedule that ends closest to the target there (under the ceiling) is run on the hidden
   plant: what a user without feedback would get.
3. **The campaign.** ``bmctl campaign init`` (card, ``controllers/mpc-default.toml``, the target,
   seed 0), then every 30 min: ``campaign advise --json``, ``campaign decide --accept``, the hidden
   plant runs the advice (milling first, vial temperature watched every 3 min),
   ``campaign log`` with the vial reading, and every hour a 300-particle micrograph table of the
   hidden plant through ``campaign sample``.

Printed and written to ``results/hidden_mills.json`` (``bmctl.results``): per case the final error,
the peak vial temperature, the longest idle stretch and the idle hours while milling was still
needed (the plant more than 2 % from the target during a rest), the advice times (first, median,
largest; wall and CPU of the ``advise`` process, with the load average), the samples taken (and how
many on request), and the plain schedule's error; the summary (median and worst error, largest
excess over the ceiling, longest idle stretch, cases where accepting every advice beat the plain
schedule, samples).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
CONTROLLER = ROOT / "controllers" / "mpc-default.toml"
CEILING_C = 80.0
INTERVAL_H = 0.5
SAMPLE_EVERY_H = 1.0
SAMPLE_PARTICLES = 300
#: a rest counts as idle while milling is still needed when the plant is this far from the target
NEED_TOL = 0.02
WATCH_H = 0.05  # the plant's vial temperature is read this often (3 min)
#: the fastest plain schedule of the sweep (rpm): every hidden mill must reach it
SWEEP_RPM_MAX = 500.0
#: the defaults of the flags that change the protocol: a run off them must name its results
PARTICLES = 5000
SEED = 0
#: the file this script writes into its ``--out`` folder: only a folder holding it is ever emptied
OUT_MARKER = ".hidden_mills-out"
#: a ``--results-name``: a plain file name (``.json`` may be added)
RESULTS_NAME = re.compile(r"^[A-Za-z0-9_-]{1,100}$")


@dataclass(frozen=True)
class Case:
    name: str
    gamma: float
    delta: float
    field: str  # "section.key"
    value: float
    hours: float
    rpm_ref: float  # the reference plain schedule (constant rpm) that defines the target
    also: tuple[tuple[str, float], ...] = ()  # more card fields changed ("section.key", value), in order

    def changes(self) -> tuple[tuple[str, float], ...]:
        """Every card field the mill changes beside gamma and delta: ``field`` first, then ``also``."""
        return ((self.field, self.value),) + tuple(self.also)


CASES = (
    Case("A", 1.5, 0.6, "mill.ball_to_powder_ratio", 11.0, 12.0, 260.0),
    Case("B", 0.7, 1.3, "mill.ball_to_powder_ratio", 9.0, 8.0, 300.0),
    Case("C", 1.3, 0.7, "mill.ball_count", 11, 12.0, 320.0),
    Case("D", 0.6, 1.0, "mill.ball_to_powder_ratio", 10.5, 12.0, 220.0),
    Case("E", 1.0, 1.6, "mill.ball_diameter_m", 0.0105, 10.0, 300.0),
    Case("F", 1.6, 1.3, "mill.ball_to_powder_ratio", 9.5, 12.0, 340.0),
    Case("G", 0.8, 0.65, "mill.ball_count", 9, 12.0, 280.0),
)
#: mills drawn after the controller's settings were fixed, never used to choose them (``--cases H,I,J,K,L``)
HELD_OUT = (
    Case("H", 0.6, 1.6, "mill.ball_diameter_m", 0.012, 10.0, 360.0),
    Case("I", 1.6, 0.6, "mill.ball_to_powder_ratio", 12.0, 8.0, 200.0),
    Case("J", 1.0, 1.0, "mill.ball_count", 13, 12.0, 420.0),
    Case("K", 1.2, 0.8, "mill.ball_diameter_m", 0.009, 6.0, 150.0),
    Case("L", 0.75, 1.45, "mill.ball_to_powder_ratio", 8.0, 12.0, 240.0),
)


#: card fields a hidden mill may not change, and why: the hidden plant does not read them, or the
#: mill's own multipliers set them
NOT_THE_PLANT = {
    "process": "the card's recipe does not change the hidden plant (the batch is the mill's hours, the speeds "
               "are the sweep's and the advice's)",
    "validity": "where the card holds does not change the hidden plant",
    "simulation.particles": "the hidden plant's particles are --particles",
    "simulation.record_every_h": "the recording interval does not change the hidden plant",
    "stochastic.gamma_per_um2": "set through gamma_mult (the card's gamma times it)",
    "stochastic.delta_per_um2": "set through delta_mult (the card's delta times it)",
}


def load_mills(path: Path, card_path: Path = CARD) -> tuple[Case, ...]:
    """Hidden mills from a TOML file (``--mills``): ``[[mill]]`` tables with ``name``, ``gamma_mult``,
    ``delta_mult``, ``field`` (a numeric card field as ``section.key``), ``value``, ``hours`` and
    ``rpm_ref`` (the reference constant rpm that defines the target, in the sweep's 100-460 rpm);
    optionally ``[mill.also]``, more card fields the mill changes (``"section.key" = value``, up to 8).
    Every hidden card (``card_path`` changed) is built and validated here; a problem is one
    :class:`~bmctl.errors.InputError` line naming the file and the field."""
    import math
    from typing import Annotated

    from pydantic import Field, ValidationError, field_validator, model_validator

    from bmctl.config import Finite, Strict, format_validation_error, load_card, read_toml, validate
    from bmctl.errors import InputError
    from bmctl.limits import HOURS_MIN

    base = load_card(card_path).model_dump()  # the fields a hidden mill may change

    def _finite_number(v):  # one message for a text, a bool, nan or inf (not the int branch's)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ValueError(f"must be a finite number (got {v!r})")
        return v

    def _numeric_card_field(v: str) -> str:  # a numeric card field the hidden plant reads
        sec, key = v.split(".")
        cur = base.get(sec)
        if not isinstance(cur, dict) or key not in cur:
            raise ValueError(f"not a field of the card {Path(card_path).name} (got {v!r})")
        if cur[key] is None:
            raise ValueError(f"not set on the card {Path(card_path).name}: a hidden mill changes a number the "
                             f"card gives (got {v!r})")
        if isinstance(cur[key], bool) or not isinstance(cur[key], (int, float)):
            raise ValueError(f"not a numeric card field (got {v!r})")
        why = NOT_THE_PLANT.get(v, NOT_THE_PLANT.get(sec))
        if why:
            raise ValueError(f"{why} (got {v!r})")
        return v

    class MillRow(Strict):
        name: Annotated[str, Field(pattern=r"^[A-Za-z0-9_-]{1,16}$")]
        gamma_mult: Annotated[float, Field(ge=0.1, le=10)]
        delta_mult: Annotated[float, Field(ge=0.1, le=10)]
        field: Annotated[str, Field(pattern=r"^[a-z_]+\.[A-Za-z0-9_]+$")]
        value: int | Finite  # an integer field (ball_count) keeps its type
        hours: Annotated[float, Field(ge=max(HOURS_MIN, INTERVAL_H), le=48)]
        rpm_ref: Annotated[float, Field(ge=100, le=460)]
        also: Annotated[dict[str, int | Finite], Field(max_length=8)] = {}

        @field_validator("value", mode="before")
        @classmethod
        def _a_number(cls, v):  # one message for a text, a bool, nan or inf (not the int branch's)
            return _finite_number(v)

        @field_validator("also", mode="before")
        @classmethod
        def _more_fields(cls, v):  # each key a numeric card field the plant reads, each value a number
            if not isinstance(v, dict):
                return v  # pydantic names the type
            for k, x in v.items():
                if not isinstance(k, str) or not re.match(r"^[a-z_]+\.[A-Za-z0-9_]+$", k):
                    raise ValueError(f"keys are card fields as \"section.key\" (got {k!r})")
                _numeric_card_field(k)
                try:
                    _finite_number(x)
                except ValueError as exc:
                    raise ValueError(f"{k}: {exc}") from None
            return v

        @model_validator(mode="after")
        def _field_once(self):
            if self.field in self.also:
                raise ValueError(f"also: {self.field} is the mill's field already (give it once)")
            return self

        @field_validator("hours")
        @classmethod
        def _last_interval(cls, v: float) -> float:  # the campaign logs no interval under 1 s
            rest = v % INTERVAL_H
            if 1e-9 < rest < HOURS_MIN:
                raise ValueError(f"leaves a last interval of {rest * 3600:.2g} s after the {INTERVAL_H:g} h advice "
                                 f"intervals, under the 1 s the campaign can log (got {v!r})")
            return v

        @field_validator("field")
        @classmethod
        def _field(cls, v: str) -> str:
            return _numeric_card_field(v)

    class MillSet(Strict):
        mill: Annotated[list[MillRow], Field(min_length=1, max_length=64)]

        @model_validator(mode="after")
        def _unique(self):
            names = [m.name for m in self.mill]
            dup = sorted({n for n in names if names.count(n) > 1})
            if dup:
                raise ValueError(f"mill: names must be unique (repeated: {', '.join(dup)})")
            return self

    ms = validate(MillSet, read_toml(path), str(path))
    cases = []
    for i, m in enumerate(ms.mill):
        case = Case(m.name, m.gamma_mult, m.delta_mult, m.field, m.value, m.hours, m.rpm_ref, tuple(m.also.items()))
        try:
            hidden_card(case, card_path)
        except ValidationError as exc:
            raise InputError(format_validation_error(f"{path}: mill[{i}] ({m.name}): the hidden card", exc)) from None
        cases.append(case)
    return tuple(cases)


def resolve_out(text: str) -> Path:
    """``--out`` as an absolute path, resolved once against the current folder (symbolic links
    followed): the campaigns (``bmctl`` runs in the repository) and the sample tables (written here)
    then go to the same folder wherever the script is started from.

    Examples
    --------
    >>> resolve_out("out/hidden_mills").is_absolute()
    True
    """
    from bmctl.errors import InputError

    if not os.fspath(text).strip():
        raise InputError("--out: must name a folder (got '')")
    return Path(os.path.realpath(os.fspath(text)))


def check_out(out: Path) -> Path:
    """Refuse an ``--out`` this run may not empty, before anything is written: it must be a new
    folder, an empty one, or one this script wrote (it holds :data:`OUT_MARKER`); a folder holding
    anything else is never deleted. Raises a one-line :class:`~bmctl.errors.InputError`."""
    from bmctl.commands._args import output_path
    from bmctl.errors import InputError

    output_path(out, "--out")  # a folder (or none yet) that can be written
    try:
        foreign = out.is_dir() and any(out.iterdir()) and not (out / OUT_MARKER).is_file()
    except OSError as exc:
        raise InputError(f"--out: cannot read {out}: {exc.strerror or exc}") from None
    if foreign:
        raise InputError(f"--out: {out} holds files this script did not write (no {OUT_MARKER} in it); give a new "
                         "or empty folder, or remove it yourself")
    return out


def claim_out(out: Path) -> None:
    """Make ``out`` this run's: checked again (:func:`check_out`), created, emptied only when it
    holds :data:`OUT_MARKER` (an earlier run's campaigns), and marked first thing."""
    check_out(out)
    out.mkdir(parents=True, exist_ok=True)
    if (out / OUT_MARKER).is_file():
        for p in out.iterdir():
            if p.name != OUT_MARKER:
                shutil.rmtree(p) if p.is_dir() and not p.is_symlink() else p.unlink()
    (out / OUT_MARKER).write_text("campaign folders of benchmarks/hidden_mills.py; its next run with this --out "
                                  "replaces them\n")


def results_name(text: str) -> str:
    """``--results-name``: a plain file name under ``results/`` (a ``.json`` ending is dropped).

    Examples
    --------
    >>> results_name("hidden_mills_seed1.json")
    'hidden_mills_seed1'
    """
    from bmctl.errors import InputError, quote

    stem = text.removesuffix(".json")
    if not RESULTS_NAME.match(stem):
        raise InputError(f"--results-name: must be a plain file name of letters, digits, _ and - (got {quote(text)})")
    return stem


def read_results(name: str, flag: str, keys: tuple[str, ...] = ("cases",)) -> dict:
    """``results/<name>.json`` with its ``keys`` present and ``cases`` a non-empty list of
    cases with step logs, or a one-line :class:`~bmctl.errors.InputError` naming ``flag`` and the file."""
    from bmctl.errors import InputError
    from bmctl.results import results_path

    path = results_path(name)
    if not path.is_file():
        raise InputError(f"{flag}: no results file {_shown(path)}")
    try:
        rec = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise InputError(f"{flag}: {_shown(path)}: not a readable results file ({exc})") from None
    missing = [k for k in keys if not isinstance(rec, dict) or k not in rec]
    cases = rec.get("cases") if isinstance(rec, dict) else None
    step_keys = ("t_h", "rpm", "mill_min", "plant_s_mean_um", "estimate_s_mean_um")
    if missing or not isinstance(cases, list) or not cases or not all(
            isinstance(c, dict) and all(k in c for k in ("case", "target_s_mean_um", "final_s_mean_um", "error_pct"))
            and isinstance(c.get("steps"), list) and c["steps"]
            and all(isinstance(st, dict) and all(k in st for k in step_keys) for st in c["steps"]) for c in cases):
        raise InputError(f"{flag}: {_shown(path)} is not a hidden-mill results file (no cases with step logs"
                         f"{'; missing ' + ', '.join(missing) if missing else ''})")
    return rec


def _shown(path: Path) -> str:
    """A path as a results file records it: relative to the repository when inside it."""
    p = Path(path).resolve()
    return str(p.relative_to(ROOT) if p.is_relative_to(ROOT) else p)


def hidden_card(case: Case, card_path: Path = CARD):
    """The hidden plant's card: the given card (the lab card by default) with gamma, delta and the
    mill's other fields changed (``field``, then ``also`` in order)."""
    from bmctl.config import load_card, with_factors

    card = with_factors(load_card(card_path), case.gamma, case.delta)
    d = card.model_dump()
    for field, value in case.changes():
        sec, key = field.split(".")
        if key == "ball_diameter_m":  # one ball's mass follows its size
            d["material"]["impactor_mass_kg"] *= (value / d["mill"]["ball_diameter_m"]) ** 3
        elif key == "ball_density_kg_m3":  # and its density
            d["material"]["impactor_mass_kg"] *= value / d["mill"]["ball_density_kg_m3"]
        d[sec][key] = value
    return type(card).model_validate(d)


def plain_schedules(hours: float) -> list[tuple[str, list]]:
    """The plain schedules of the sweep: (name, [(hours, rpm), ...])."""
    out = [(f"{r:.0f} rpm continuous", [(hours, float(r))]) for r in range(100, 461, 20)]
    for r in (400.0, 450.0, SWEEP_RPM_MAX):
        cyc = []
        t = 0.0
        while t < hours - 1e-9:
            m = min(0.5, hours - t)
            cyc.append((m, r))
            t += m
            if t < hours - 1e-9:
                rest = min(1 / 6, hours - t)
                cyc.append((rest, 0.0))
                t += rest
        out.append((f"{r:.0f} rpm 30/10 min", cyc))
    return out


def run_plain(card, segments, particles: int, seed: int) -> tuple[float, float]:
    """(final mean size µm, peak vial temperature °C) of a schedule on a plant of ``card``."""
    from bmctl.loop import run_open_loop
    from bmctl.plant.plant import Plant

    plant = Plant(card, np.random.default_rng(seed), particles)
    peak = [plant.temperature_c]
    run_open_loop(plant, list(segments), WATCH_H, lambda t, m: peak.append(m.temperature_c))
    return float(plant.moments()["s_mean_um"]), float(max(peak))


def sweep(card, hours: float, particles: int, seed: int) -> list[dict]:
    return [dict(zip(("name", "s_mean_um", "peak_c"), (name, *run_plain(card, segs, particles, seed))))
            | {"segments": segs} for name, segs in plain_schedules(hours)]


def sample_noise(particles: int, seed: int, repeats: int = 400, sample_particles: int = SAMPLE_PARTICLES) -> dict:
    """How much the mean of one hourly micrograph sample scatters around the plant's mean: mill G
    after 3 h at 140 rpm (its state when the campaign first reached the target), ``repeats`` samples."""
    from bmctl.measure.sampler import micrograph_sample
    from bmctl.plant.plant import Plant

    case = next(c for c in CASES if c.name == "G")
    g_plant, g_sample = (np.random.default_rng(s) for s in np.random.SeedSequence([seed, 99]).spawn(2))
    plant = Plant(hidden_card(case), g_plant, particles)
    plant.advance(140.0, 3.0, milling=1.0)
    mean = float(plant.moments()["s_mean_um"])
    means = np.array([np.mean(micrograph_sample(plant.s * 1e6, plant.r, sample_particles, g_sample).s_um)
                      for _ in range(repeats)])
    return {"plant_s_mean_um": mean, "sample_mean_avg_um": float(means.mean()),
            "sample_mean_sd_um": float(means.std(ddof=1)),
            "sample_mean_rel_sd_pct": float(100 * means.std(ddof=1) / mean), "repeats": repeats}


def cli(args: list[str], env: dict) -> tuple[str, float, float]:
    """Run ``python -m bmctl ARGS``; (stdout, wall s, CPU s of the child)."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "bmctl", *args], cwd=ROOT, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode != 0:
        raise RuntimeError(f"bmctl {' '.join(args)}: exit {p.returncode}: {p.stderr.strip()[-400:]}")
    return p.stdout, wall, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)


def case_seeds(seed: int, name: str) -> np.random.SeedSequence:
    """The seed sequence of one mill's campaign (its plant and its samples): the run's seed and the
    code points of the mill's name (a one-letter name: ``[seed, ord(name)]``).

    Examples
    --------
    >>> case_seeds(1, "C").entropy, case_seeds(1, "T12").entropy
    ([1, 67], [1, 84, 49, 50])
    """
    return np.random.SeedSequence([int(seed), *map(ord, name)])


def run_campaign(case: Case, target_um: float, folder: Path, particles: int, seed: int, env: dict,
                 energy_mult: bool = True, sample_particles: int = SAMPLE_PARTICLES,
                 on_request: bool = False, controller: Path = CONTROLLER,
                 sample_every_h: float = SAMPLE_EVERY_H, sample_feed: bool = False, card_path: Path = CARD,
                 moment_noise_at: str = "update") -> dict:
    """The scripted operator: advise, accept, run the hidden plant, log, sample every
    ``sample_every_h`` (hourly) and at the batch end; with
    ``on_request`` also take the extra sample an advice asks for (``sample_first``), then advise again;
    with ``sample_feed`` also sample the feed at 0 h, before the first advice."""
    from bmctl.measure.sampler import micrograph_sample
    from bmctl.measure.tables import write_table
    from bmctl.plant.plant import Plant

    folder = Path(os.path.abspath(folder))  # bmctl runs in the repository: a relative folder would differ there
    card = hidden_card(case, card_path)
    ss = case_seeds(seed, case.name)
    g_plant, g_sample = (np.random.default_rng(s) for s in ss.spawn(2))
    plant = Plant(card, g_plant, particles)
    cli(["campaign", "init", str(folder), "--model", str(card_path), "--controller", str(controller), "--target",
         f"s_mean_um={target_um:.4f}", "--hours", repr(float(case.hours)), "--seed", "0",
         *([] if energy_mult else ["--no-energy-mult"]),
         *([] if moment_noise_at == "update" else ["--moment-noise-at", moment_noise_at])], env)
    t, peak = 0.0, plant.temperature_c
    advise_wall, advise_cpu, steps = [], [], []
    samples = extra = 0
    watch = []  # per 3-min step: (length h, resting throughout, plant's relative error)

    def take_sample(name: str) -> None:  # a micrograph table of the hidden plant, sampled at the logged time
        tab = micrograph_sample(plant.s * 1e6, plant.r, sample_particles, g_sample)
        path = folder / name
        write_table(path, tab)
        cli(["campaign", "sample", str(folder), "--at-h", f"{t:.10g}", str(path)], env)

    if sample_feed:  # the feed, before the first advice (the filter reads it: FilterSettings.feed_log_std)
        take_sample("sample-00.00h-feed.csv")
        samples += 1
    while t < case.hours - 1e-9:
        out, wall, cpu = cli(["campaign", "advise", str(folder), "--json"], env)
        a = json.loads(out)
        advise_wall.append(wall)
        advise_cpu.append(cpu)
        asked = None
        while on_request and a.get("sample_first"):  # the advice caps the samples at one batch time
            asked = a["sample_first"]
            take_sample(f"sample-{t:05.2f}h-extra{extra + 1}.csv")
            samples, extra = samples + 1, extra + 1
            out, wall, cpu = cli(["campaign", "advise", str(folder), "--json"], env)
            a = json.loads(out)
            advise_wall.append(wall)
            advise_cpu.append(cpu)
        cli(["campaign", "decide", str(folder), "--accept"], env)
        nx = a["next"]
        dt = float(nx["interval_h"])
        mill_min = int(nx["mill_min"])
        rpm = float(nx["rpm"]) if mill_min > 0 else 0.0
        milling = mill_min / (dt * 60.0)
        steps.append({"t_h": t, "rpm": rpm, "mill_min": mill_min, "plant_s_mean_um": plant.moments()["s_mean_um"],
                      "estimate_s_mean_um": a["estimate"]["s_mean_um"], "plan": a.get("solver", "")[:120],
                      **({"sample_first": asked} if on_request else {})})
        n = max(1, int(round(dt / WATCH_H)))
        for j in range(n):  # milling first, then the rest; the vial read every 3 min
            a0, b0 = j * dt / n, (j + 1) * dt / n
            m = max(0.0, min(b0, milling * dt) - a0) / (b0 - a0)
            err = abs(plant.moments()["s_mean_um"] - target_um) / target_um
            watch.append((b0 - a0, m <= 0.0, err))
            plant.advance(rpm, b0 - a0, milling=m)
            peak = max(peak, plant.temperature_c)
        cli(["campaign", "log", str(folder), "--rpm", f"{rpm:g}", "--hours", f"{dt:.10g}", "--milling",
             f"{milling:.10g}", "--temperature-c", f"{plant.temperature_c:.2f}"], env)
        t += dt
        if abs(t / sample_every_h - round(t / sample_every_h)) < 1e-6 or t >= case.hours - 1e-9:
            take_sample(f"sample-{t:05.2f}h.csv")
            samples += 1
    idle, run = [], 0.0  # rest stretches that began with the plant more than NEED_TOL from the target
    for k, (h, resting, err) in enumerate(watch):
        if resting and (run > 0 or err > NEED_TOL):
            run += h
        elif run > 0:
            idle.append(run)
            run = 0.0
    if run > 0:
        idle.append(run)
    final = plant.moments()["s_mean_um"]
    later = advise_wall[1:] or advise_wall
    return {"final_s_mean_um": final, "error_pct": 100 * (final - target_um) / target_um,
            "peak_c": peak, "idle_needed_h": float(sum(idle)),
            "longest_idle_needed_h": float(max(idle, default=0.0)),
            "advise_first_s": advise_wall[0], "advise_first_cpu_s": advise_cpu[0],
            "advise_later_median_s": float(np.median(later)), "advise_later_max_s": float(np.max(later)),
            "advise_later_median_cpu_s": float(np.median(advise_cpu[1:] or advise_cpu)),
            "advices": len(advise_wall), "samples": samples, "extra_samples": extra, "steps": steps}


def figure(rec: dict, path: Path) -> Path:
    """One panel per mill from a results file's step logs: the plant's and the estimate's mean size at
    each advice, the target, and the advised rpm (bars, right axis; the bar's width is the milling time)."""
    from bmctl.io import pyplot, savefig

    plt = pyplot()
    rows = rec["cases"]
    ncol = min(4, len(rows))
    nrow = -(-len(rows) // ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.6 * ncol, 2.9 * nrow), squeeze=False, sharex=False)
    for ax, r in zip(axes.flat, rows):
        st = r["steps"]
        t = np.array([s["t_h"] for s in st])
        ax2 = ax.twinx()
        ax2.bar(t, [s["rpm"] for s in st], width=[s["mill_min"] / 60.0 for s in st], align="edge",
                color="0.85", zorder=0)
        ax2.set_ylim(0, 1000)
        ax2.set_yticks([0, 250, 500])
        ax2.tick_params(labelsize=7)
        ax.set_zorder(ax2.get_zorder() + 1)
        ax.patch.set_visible(False)
        t_end = float(t[-1]) + INTERVAL_H  # the batch end: the plant's final size
        ax.plot(np.append(t, t_end), [s["plant_s_mean_um"] for s in st] + [r["final_s_mean_um"]], "-", color="C0",
                lw=1.4, label="plant")
        ax.plot(t, [s["estimate_s_mean_um"] for s in st], ".", color="C1", ms=4, label="estimate")
        ax.axhline(r["target_s_mean_um"], color="k", ls="--", lw=0.8, label="target")
        ax.set_title(f"{r['case']}: {r['error_pct']:+.1f} % at the end", fontsize=9)
        ax.set_xlabel("batch time (h)", fontsize=8)
        ax.set_ylabel("mean size s (µm)", fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(rows):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7, loc="best")
    fig.suptitle(f"hidden mills, every advice accepted (grey bars: advised rpm, right axis) - {rec['command']}",
                 fontsize=8)
    fig.tight_layout()
    savefig(fig, path, dpi=110)
    return path


def table(rows: list[dict], summary: dict, name: str = "hidden_mills") -> str:
    """The Markdown table of docs/control.md, its measured numbers in markers pointing at
    ``results/<name>.json`` (the file the run writes)."""
    from bmctl.results import marked

    def m(i, key, fmt):
        return marked(name, f"cases.{i}.{key}", rows[i][key], fmt)

    out = ["| mill | γ, δ | also changed | batch h | target s_mean µm | campaign error % | peak °C | "
           "idle while needed h (longest) | plain schedule chosen on the card | its error % |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for i, r in enumerate(rows):
        def inp(v):  # an input of the case (a factor touching × or a decimal would look measured)
            return f"<!--in-->{v:g}<!--/in-->"

        def shown(v):  # a whole number as is, a decimal marked as an input
            return f"{v:g}" if float(v).is_integer() else inp(v)

        changed = "; ".join(f"{f.split('.')[1]} = {shown(v)}"
                            for f, v in [(r["field"], r["value"]), *r.get("also", {}).items()])
        out.append(f"| {r['case']} | ×{inp(r['gamma_mult'])}, ×{inp(r['delta_mult'])} | {changed} | {r['hours']:g} | {m(i, 'target_s_mean_um', '{:.2f}')} | "
                   f"{m(i, 'error_pct', '{:+.2f}')} | {m(i, 'peak_c', '{:.1f}')} | {m(i, 'idle_needed_h', '{:.2f}')} "
                   f"({m(i, 'longest_idle_needed_h', '{:.2f}')}) | {r['plain_schedule']} | "
                   f"{m(i, 'plain_error_pct', '{:+.1f}')} |")
    sm = {k: marked(name, f"summary.{k}", summary[k], f) for k, f in (
        ("median_error_pct", "{:.2f}"), ("worst_error_pct", "{:.2f}"), ("max_over_ceiling_c", "{:+.1f}"),
        ("longest_idle_needed_h", "{:.2f}"), ("plain_median_error_pct", "{:.1f}"), ("plain_worst_error_pct", "{:.1f}"),
        ("campaign_beats_plain", "{:d}"))}
    out.append("")
    out.append(f"Median |error| {sm['median_error_pct']} %, worst {sm['worst_error_pct']} %; the largest peak "
               f"{sm['max_over_ceiling_c']} °C from the ceiling; the longest idle stretch while milling was still "
               f"needed {sm['longest_idle_needed_h']} h. The plain schedules chosen on the card: median "
               f"{sm['plain_median_error_pct']} %, worst {sm['plain_worst_error_pct']} %; accepting every advice "
               f"was closer in {sm['campaign_beats_plain']} of {len(rows)} mills.")
    return "\n".join(out)


class _Parser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one :class:`~bmctl.errors.InputError` line (exit 2)."""

    def error(self, message: str):  # noqa: D401 - argparse API
        from bmctl.errors import InputError

        raise InputError(message)


def _every_h(text: str) -> float:
    """``--sample-every-h``: a multiple of the advice interval, at most the longest batch (1000 h)."""
    from bmctl.errors import InputError, finite_float
    from bmctl.limits import HOURS_MAX

    v = finite_float(text, "--sample-every-h")
    k = v / INTERVAL_H
    if not (1 <= k <= HOURS_MAX / INTERVAL_H and abs(k - round(k)) < 1e-9):
        raise InputError(f"--sample-every-h: must be a positive multiple of the {INTERVAL_H:g} h interval, at most "
                         f"{HOURS_MAX:g} h (got {text})")
    return v


def main() -> None:
    """Run the benchmark; bad input (a flag, a file) is one line on stderr and exit code 2, before
    anything is written or deleted."""
    from bmctl.errors import InputError, one_line

    try:
        _main()
    except InputError as exc:
        print(f"hidden_mills.py: error: {one_line(str(exc))}", file=sys.stderr)
        sys.exit(2)


def _main() -> None:
    from bmctl.commands._args import int_arg, output_path
    from bmctl.config import load_card
    from bmctl.errors import InputError
    from bmctl.results import write_results

    ap = _Parser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", help="comma-separated case names (default A-G, or every mill of --mills)")
    ap.add_argument("--mills", metavar="TOML",
                    help="hidden mills of your own instead of A-L ([[mill]] tables: name, gamma_mult, delta_mult, "
                         "field, value, hours, rpm_ref; e.g. benchmarks/mills-unseen.toml)")
    ap.add_argument("--particles", type=int_arg("--particles", 100, 10_000_000), default=PARTICLES,
                    help=f"plant particles, 100 to 10,000,000 (default {PARTICLES})")
    ap.add_argument("--sample-particles", type=int_arg("--sample-particles", 1, 1_000_000), default=SAMPLE_PARTICLES,
                    help=f"particles in each hourly micrograph sample, 1 to 1,000,000 (default {SAMPLE_PARTICLES})")
    ap.add_argument("--sample-every-h", type=_every_h, default=SAMPLE_EVERY_H,
                    help=f"hours between the operator's samples, a multiple of the {INTERVAL_H:g} h interval "
                         f"up to 1000 h (default {SAMPLE_EVERY_H:g})")
    ap.add_argument("--seed", type=int_arg("--seed", 0), default=SEED, help=f"a non-negative integer (default {SEED})")
    ap.add_argument("--workers", type=int_arg("--workers", 1, 256), default=1,
                    help="mills run side by side (default 1); each mill's campaign is seeded by its name, so the "
                         "results are the same for any number, but advice times then share the machine")
    ap.add_argument("--out", default=None,
                    help=f"the campaign folders go here (default out/<--results-name> in the repository, so that "
                         f"runs of different sets can go side by side; a relative path "
                         f"is taken from the current folder). A new or empty folder is used; a folder an earlier run "
                         f"wrote (it holds the {OUT_MARKER} file each run writes) is emptied and reused; a folder "
                         f"holding anything else is refused, never deleted")
    ap.add_argument("--no-results", action="store_true", help="do not write results/hidden_mills.json")
    ap.add_argument("--no-energy-mult", action="store_true",
                    help="campaigns started with --no-energy-mult (the filter learns gamma_mult, delta_mult only)")
    ap.add_argument("--table", action="store_true", help="print the docs table from results/hidden_mills.json")
    ap.add_argument("--figure", metavar="PNG",
                    help="draw the step logs of results/<--results-name>.json (one panel per mill) to PNG and exit")
    ap.add_argument("--noise", action="store_true",
                    help="measure how much one sample's mean scatters (mill G after 3 h at 140 rpm): "
                         "results/hidden_mills_noise.json")
    ap.add_argument("--sample-on-request", action="store_true",
                    help="the operator also takes the extra sample an advice asks for (sample_first), then "
                         "advises again")
    ap.add_argument("--sample-feed", action="store_true",
                    help="the operator also samples the feed at 0 h, before the first advice")
    ap.add_argument("--moment-noise-at", choices=("update", "sample"), default="update",
                    help="the campaigns' `campaign init --moment-noise-at`: when the filter draws the moments' "
                         "deferred model noise (default: update)")
    ap.add_argument("--card", metavar="TOML",
                    help=f"the card the campaigns are given and the hidden mills change (default "
                         f"{CARD.relative_to(ROOT)}; it needs its moment coefficients, <card>.moments.toml)")
    ap.add_argument("--controller", metavar="TOML",
                    help=f"the campaign's controller config (default {CONTROLLER.relative_to(ROOT)})")
    ap.add_argument("--results-name", type=results_name, default="hidden_mills",
                    help="results file name, letters, digits, _ and - (a subset of the cases or another seed: "
                         "e.g. hidden_mills_seed1)")
    a = ap.parse_args()
    # once, here: every later use (and every bmctl run) gets this absolute folder
    a.out = resolve_out(a.out if a.out is not None else str(ROOT / "out" / a.results_name))
    if a.figure:
        from matplotlib.backend_bases import FigureCanvasBase

        kinds = FigureCanvasBase.get_supported_filetypes()
        if Path(a.figure).suffix.lower().lstrip(".") not in kinds:
            raise InputError(f"--figure: {a.figure}: the file name must end in an image format "
                             f"({', '.join('.' + k for k in sorted(kinds))})")
        path = output_path(a.figure, "--figure", folder=False)
        rec = read_results(a.results_name, "--results-name", ("cases", "command"))
        print("wrote", figure(rec, path))
        return
    if a.table:
        rec = read_results("hidden_mills", "--table", ("cases", "summary"))
        print(table(rec["cases"], rec["summary"]))
        return
    if a.noise:
        changed = (("--particles", a.particles != PARTICLES), ("--seed", a.seed != SEED),
                   ("--sample-particles", a.sample_particles != SAMPLE_PARTICLES))
        for flag, given in changed:  # a run off the default protocol must not overwrite the default's results
            if given and a.results_name == "hidden_mills" and not a.no_results:
                raise InputError(f"{flag}: name the results of --noise (--results-name) or pass --no-results")
        rec = sample_noise(a.particles, a.seed, sample_particles=a.sample_particles)
        print(f"one {a.sample_particles}-particle sample's mean: sd {rec['sample_mean_rel_sd_pct']:.2f} % of the "
              f"plant's mean ({rec['repeats']} samples; plant {rec['plant_s_mean_um']:.2f} µm, sample means average "
              f"{rec['sample_mean_avg_um']:.2f} µm)")
        if not a.no_results:
            name = "hidden_mills_noise" if a.results_name == "hidden_mills" else a.results_name
            print("wrote", write_results(name, rec,
                                         settings={"case": "G", "rpm": 140.0, "hours": 3.0, "particles": a.particles,
                                                   "seed": a.seed, "sample_particles": a.sample_particles},
                                         command="python benchmarks/hidden_mills.py --noise" + (
                                             "" if name == "hidden_mills_noise" else
                                             (f" --particles {a.particles}" if a.particles != PARTICLES else "")
                                             + (f" --seed {a.seed}" if a.seed != SEED else "")
                                             + f" --sample-particles {a.sample_particles} --results-name {name}")))
        return
    from bmctl.control.config import load_controller

    card_path = Path(a.card).resolve() if a.card else CARD
    # a bad card, mills or controller file: one line, exit 2, before anything is written
    card = load_card(card_path)
    if card.mill.rpm_max < SWEEP_RPM_MAX:  # the sweep's fastest schedule would be refused by the plant
        raise InputError(f"--card {a.card or _shown(card_path)}: mill.rpm_max: the sweep runs up to {SWEEP_RPM_MAX:g} "
                         f"rpm (the paper's 30/10 min schedule), above this mill's {card.mill.rpm_max:g} rpm: the "
                         f"benchmark needs a mill that reaches {SWEEP_RPM_MAX:g} rpm")
    if a.card:  # the campaign refuses a card without its own moment coefficients: say so before any sweep
        from bmctl.moments.forcard import for_card

        for_card(card_path)
    pool = load_mills(Path(a.mills), card_path) if a.mills else CASES + HELD_OUT
    ctrl_cfg = load_controller(a.controller or CONTROLLER)
    top = max(SWEEP_RPM_MAX, min(ctrl_cfg.bounds.rpm_max, card.mill.rpm_max))
    for i, case in enumerate(pool):  # the operator cannot run an advice above the mill's top speed
        rpm_max = hidden_card(case, card_path).mill.rpm_max
        if rpm_max < top:
            where = f"{a.mills}: mill[{i}] ({case.name})" if a.mills else f"--card {a.card}: mill {case.name}"
            raise InputError(f"{where}: mill.rpm_max: the hidden mill must reach the "
                             f"{top:g} rpm that the sweep and the controller may ask for (got {rpm_max:g}); a "
                             "mill's top speed is not hidden from its operator: give it on the card and the "
                             "controller's [bounds] instead")
    controller = Path(a.controller).resolve() if a.controller else CONTROLLER
    names = [s.strip() for s in (a.cases or ",".join(c.name for c in (pool if a.mills else CASES))).split(",")
             if s.strip()]
    known = {c.name: c for c in pool}
    bad = [n for n in names if n not in known]
    if bad:
        from bmctl.errors import quote

        raise InputError(f"--cases: unknown mill(s) {', '.join(quote(n) if not n.isalnum() else n for n in bad)} "
                         f"(known: {', '.join(known)})")
    if not names:
        raise InputError(f"--cases: no mill named (known: {', '.join(known)})")
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise InputError(f"--cases: each mill once (repeated: {', '.join(twice)})")
    cases = [known[n] for n in names]
    changed = (("--card", a.card), ("--mills", a.mills), ("--controller", a.controller),
               ("--no-energy-mult", a.no_energy_mult), ("--particles", a.particles != PARTICLES),
               ("--seed", a.seed != SEED),
               ("--sample-particles", a.sample_particles != SAMPLE_PARTICLES),
               ("--sample-on-request", a.sample_on_request), ("--sample-every-h", a.sample_every_h != SAMPLE_EVERY_H),
               ("--sample-feed", a.sample_feed), ("--moment-noise-at", a.moment_noise_at != "update"))
    for flag, given in changed:  # a run off the default protocol must not overwrite the default's results
        if given and a.results_name == "hidden_mills" and not a.no_results:
            raise InputError(f"{flag}: name its results (--results-name) or pass --no-results")
    out = check_out(a.out)  # refused here, not after the sweeps; emptied only once every target is found
    card_sweeps: dict[float, list] = {}
    rows = []
    t_start = time.perf_counter()
    refs = {}
    for case in cases:  # every target first: a mill without one stops the run before any campaign
        hs = sweep(hidden_card(case, card_path), case.hours, a.particles, a.seed)
        ok = [r for r in hs[:19] if r["peak_c"] <= CEILING_C - 3.0]
        if not ok:
            where = f"{a.mills}: " if a.mills else ""
            raise InputError(f"{where}mill {case.name}: no constant speed of the sweep stays 3 °C under the "
                             f"{CEILING_C:g} °C ceiling on the hidden plant, so no target can be chosen")
        refs[case.name] = (hs, min(ok, key=lambda r: abs(float(r["name"].split()[0]) - case.rpm_ref)))
        if case.hours not in card_sweeps:  # the plain schedules the card offers, under the ceiling
            card_sweeps[case.hours] = sweep(card, case.hours, a.particles, a.seed)
            if not any(r["peak_c"] <= CEILING_C for r in card_sweeps[case.hours]):
                raise InputError(f"--card {a.card or _shown(card_path)}: no schedule of the sweep stays under the "
                                 f"{CEILING_C:g} °C ceiling on the card's plant ({case.hours:g} h), so no plain "
                                 "schedule can be chosen on it")
    claim_out(out)
    cache = Path(tempfile.mkdtemp(prefix="bmctl-hidden-cache-"))  # a fresh compile cache: first advise is cold
    env = {**os.environ, "PYTHONPATH": str(ROOT), "XDG_CACHE_HOME": str(cache), "MPLBACKEND": "Agg"}
    load0 = os.getloadavg()
    plans = []
    for case in cases:  # the target and the plain schedule chosen on the card, per mill
        hs, ref = refs[case.name]
        target = round(ref["s_mean_um"], 2)
        cs = [r for r in card_sweeps[case.hours] if r["peak_c"] <= CEILING_C]
        pick = min(cs, key=lambda r: abs(r["s_mean_um"] - target))
        plain_hidden = next(r for r in hs if r["name"] == pick["name"])
        plans.append((case, ref, target, pick, plain_hidden, 100 * (plain_hidden["s_mean_um"] - target) / target))

    def one(plan):  # a mill's campaign (its own generators, its own folder: runs side by side unchanged)
        case, ref, target, pick, _, plain_err = plan
        head = (f"case {case.name}: gamma x{case.gamma:g}, delta x{case.delta:g}, "
                f"{', '.join(f'{f} = {v:g}' for f, v in case.changes())}, "
                f"{case.hours:g} h; target s_mean_um = {target:.2f} ({ref['name']} on the hidden plant, "
                f"peak {ref['peak_c']:.1f} °C); plain schedule chosen on the card: {pick['name']} -> "
                f"{plain_err:+.1f} % on the hidden plant")
        if a.workers == 1:
            print(head, flush=True)
        res = run_campaign(case, target, out / f"case-{case.name}", a.particles, a.seed, env, not a.no_energy_mult,
                           a.sample_particles, a.sample_on_request, controller, a.sample_every_h, a.sample_feed,
                           card_path, a.moment_noise_at)
        print(("" if a.workers == 1 else head + "\n")
              + f"  campaign: final {res['final_s_mean_um']:.2f} µm ({res['error_pct']:+.2f} %), peak "
              f"{res['peak_c']:.1f} °C, idle while needed {res['idle_needed_h']:.2f} h (longest "
              f"{res['longest_idle_needed_h']:.2f} h); advise first {res['advise_first_s']:.1f} s, later median "
              f"{res['advise_later_median_s']:.1f} s (CPU {res['advise_later_median_cpu_s']:.1f} s); samples "
              f"{res['samples']} ({res['extra_samples']} on request)", flush=True)
        return res

    if a.workers == 1:
        results = [one(p) for p in plans]
    else:
        from concurrent.futures import ThreadPoolExecutor  # the work is in each mill's bmctl processes

        with ThreadPoolExecutor(max_workers=a.workers) as pool:
            results = list(pool.map(one, plans))
    for (case, ref, target, pick, plain_hidden, plain_err), res in zip(plans, results):
        rows.append({"case": case.name, "gamma_mult": case.gamma, "delta_mult": case.delta, "field": case.field,
                     "value": case.value, **({"also": dict(case.also)} if case.also else {}),
                     "hours": case.hours, "target_s_mean_um": target,
                     "reference_schedule": ref["name"], "reference_peak_c": ref["peak_c"],
                     "plain_schedule": pick["name"], "plain_error_pct": plain_err,
                     "plain_peak_c": plain_hidden["peak_c"], **{k: v for k, v in res.items() if k != "steps"},
                     "steps": res["steps"]})
    errs = np.array([abs(r["error_pct"]) for r in rows])
    plain = np.array([abs(r["plain_error_pct"]) for r in rows])
    summary = {
        "cases": len(rows), "median_error_pct": float(np.median(errs)), "worst_error_pct": float(errs.max()),
        "max_over_ceiling_c": float(max(r["peak_c"] for r in rows) - CEILING_C),
        "longest_idle_needed_h": float(max(r["longest_idle_needed_h"] for r in rows)),
        "plain_median_error_pct": float(np.median(plain)), "plain_worst_error_pct": float(plain.max()),
        "campaign_beats_plain": int(np.sum(errs < plain)),
        "samples": int(sum(r["samples"] for r in rows)), "extra_samples": int(sum(r["extra_samples"] for r in rows)),
        "advise_first_s_max": float(max(r["advise_first_s"] for r in rows)),
        "advise_first_cpu_s_max": float(max(r["advise_first_cpu_s"] for r in rows)),
        "advise_later_median_s": float(np.median([r["advise_later_median_s"] for r in rows])),
        "advise_later_median_cpu_s": float(np.median([r["advise_later_median_cpu_s"] for r in rows])),
        "load_before": list(load0), "load_after": list(os.getloadavg()),
        "wall_s": time.perf_counter() - t_start,
    }
    print("\n" + table(rows, summary, a.results_name))
    print(f"\nmedian |error| {summary['median_error_pct']:.2f} %, worst {summary['worst_error_pct']:.2f} %; "
          f"largest excess over the ceiling {summary['max_over_ceiling_c']:+.1f} °C; longest idle stretch while "
          f"needed {summary['longest_idle_needed_h']:.2f} h; plain schedules: median {summary['plain_median_error_pct']:.2f}"
          f" %, worst {summary['plain_worst_error_pct']:.2f} %; campaign better in {summary['campaign_beats_plain']} "
          f"of {len(rows)}")
    print(f"advise: first {summary['advise_first_s_max']:.1f} s wall at most; later median "
          f"{summary['advise_later_median_s']:.1f} s wall, {summary['advise_later_median_cpu_s']:.1f} s CPU; load "
          f"{load0[0]:.1f} -> {os.getloadavg()[0]:.1f}")
    shutil.rmtree(cache, ignore_errors=True)
    default_set = [c.name for c in cases] == [c.name for c in CASES]  # the default file holds A-G, in order
    if not a.no_results and (default_set or a.results_name != "hidden_mills"):
        cmd = "python benchmarks/hidden_mills.py"
        if a.results_name != "hidden_mills":
            if a.card:
                cmd += f" --card {_shown(card_path)}"
            if a.mills:
                cmd += f" --mills {_shown(Path(a.mills))}"
            cmd += f" --cases {','.join(c.name for c in cases)} --seed {a.seed}"
            cmd += (f" --particles {a.particles}" if a.particles != PARTICLES else "")
            if a.controller:
                cmd += f" --controller {_shown(controller)}"
            cmd += (" --no-energy-mult" if a.no_energy_mult else "")
            cmd += (f" --sample-particles {a.sample_particles}" if a.sample_particles != SAMPLE_PARTICLES else "")
            cmd += (f" --sample-every-h {a.sample_every_h:g}" if a.sample_every_h != SAMPLE_EVERY_H else "")
            cmd += (" --sample-on-request" if a.sample_on_request else "")
            cmd += (" --sample-feed" if a.sample_feed else "")
            cmd += (f" --moment-noise-at {a.moment_noise_at}" if a.moment_noise_at != "update" else "")
            cmd += f" --results-name {a.results_name}"
        path = write_results(a.results_name, {"summary": summary, "cases": rows},
                             settings={"cases": [c.__dict__ for c in cases], "particles": a.particles, "seed": a.seed,
                                       "controller": _shown(controller), "card": _shown(card_path),
                                       "ceiling_c": CEILING_C, "interval_h": INTERVAL_H,
                                       "sample_every_h": a.sample_every_h, "sample_particles": a.sample_particles,
                                       "need_tol": NEED_TOL, "energy_mult": not a.no_energy_mult,
                                       "sample_on_request": a.sample_on_request, "sample_feed": a.sample_feed,
                                       "moment_noise_at": a.moment_noise_at},
                             command=cmd)
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
