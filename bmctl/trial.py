"""Closed-loop trials: plant -> micrograph sampler -> particle filter -> controller -> plant.

A trial is a :class:`bmctl.loop.ClosedLoop` built from a scenario, written step by step to disk
so that a killed trial loses nothing and resumes:

* ``trajectory.csv`` -- one row per control interval, appended and flushed (fsync) each step;
* ``checkpoint.npz`` -- the full state after the last written row as plain data (plant, filter,
  sampler and controller states, their generators' states included; :mod:`bmctl.checkpoint`),
  replaced atomically each step;
* ``summary.json`` and figures when the trial ends.

Resuming (``--resume DIR``) keeps the checkpoint's rows of ``trajectory.csv`` (a torn last row,
cut mid-write, is dropped) and carries on; with the same seed the result is identical to an
uninterrupted run. A damaged checkpoint or ``trial.json`` is refused with one line.
"""

from __future__ import annotations

import csv
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import io
from .checkpoint import load_state, save_state
from .config import ModelCard, load_card, with_factors
from .errors import InputError
from .naming import arg
from .loop import ClosedLoop, LoopConfig, StepRecord
from .scenario import TARGET_KEYS, Scenario, load_scenario, resolve

#: the plant's state at each interval's end, and its highest vial temperature within the interval
TRUE_KEYS = ("s_mean_um", "s_std_um", "r_mean", "r_std", "temperature_c", "peak_temperature_c")
EST_KEYS = ("s_mean_um", "s_std_um", "r_mean", "r_std", "temperature_c", "gamma_mult", "delta_mult")
CHECKPOINT = "checkpoint.npz"


def trajectory_header() -> list[str]:
    h = ["step", "t_h", "rpm", "milling"] + [f"true_{k}" for k in TRUE_KEYS]
    for k in EST_KEYS:
        h += [f"est_{k}", f"est_{k}_q05", f"est_{k}_q95"]
    return h + ["sampled", "ess", "solve_ms", "solver_status", "fallback"]


@dataclass
class MicrographSensor:
    """A micrograph of the plant's powder (:func:`bmctl.measure.sampler.micrograph_sample`):
    the :class:`bmctl.loop.Sensor` of a simulated trial."""

    particles: int
    um_per_px: float | None
    noise: float
    render: bool

    def sample(self, mill, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """``(s_um, r)`` of one micrograph's particle table.

        Parameters
        ----------
        mill : Plant
            Its population ``s`` (m) and ``r`` is imaged.
        rng : numpy.random.Generator
            The sampler's generator.
        """
        from .measure.sampler import micrograph_sample

        tab = micrograph_sample(mill.s * 1e6, mill.r, self.particles, rng, um_per_px=self.um_per_px,
                                noise=self.noise, render=self.render)
        return np.asarray(tab.s_um), np.asarray(tab.r)


def check_resolvable(sc: Scenario, scenario_path, card: ModelCard) -> None:
    """Refuse a pixel size at which the starting powder cannot be measured, before the trial's folder
    is made (the first sample failed after the folder and its checkpoint were written), and, with
    ``render``, one whose particles a rendered field cannot hold (the renderer drew them for minutes
    and gigabytes). The starting powder is :func:`initial_sizes`."""
    um = sc.sampling.um_per_px
    if um is None:
        return
    from .measure.sampler import MAX_DRAWS_FACTOR, MIN_AREA_PX, RENDER_PARTICLE_MAX_PX, resolvable_share

    s_um = initial_sizes(card)
    share = resolvable_share(s_um, um)
    if share * MAX_DRAWS_FACTOR < 1.0:
        raise InputError(f"{scenario_path}: sampling.um_per_px: at {um:g} µm/px {100 * share:.2g} % of the starting "
                         f"powder's particles span the {MIN_AREA_PX} px a particle needs to be measured; "
                         "give a finer pixel size")
    big = float(np.quantile(s_um, 0.99)) / um
    if sc.sampling.render and big > RENDER_PARTICLE_MAX_PX:  # the field is cut at its largest side
        raise InputError(f"{scenario_path}: sampling.um_per_px: at {um:g} µm/px the starting powder's largest "
                         f"particles are {big:.3g} px across; a rendered micrograph holds them up to "
                         f"{RENDER_PARTICLE_MAX_PX:.0f} px: give a coarser pixel size, or render = false")


def initial_sizes(card: ModelCard, n: int = 1000) -> np.ndarray:
    """The card's starting powder's sizes (µm) at ``n`` quantiles of its ``[initial]`` law: a normal law
    cut at a tenth of its mean, as the plant draws it; no random draw."""
    from scipy.stats import norm

    m, sd = card.initial.s_mean_um, card.initial.s_std_um
    if sd <= 0:
        return np.full(n, float(m))
    q = (np.arange(n) + 0.5) / n
    f_lo = norm.cdf((0.1 * m - m) / sd)
    return m + sd * norm.ppf(f_lo + q * (1.0 - f_lo))


def _plant_card(sc: Scenario, base: Path) -> ModelCard:
    card = load_card(resolve(sc.plant.model or sc.model, base))
    return with_factors(card, sc.plant.gamma_factor, sc.plant.delta_factor)


def _model_and_controller(sc: Scenario, base: Path):
    """The moment model and the controller of a scenario (no random state: rebuilt on resume)."""
    from .control import make_controller
    from .control.config import check_ceiling, load_controller, validate_controller
    from .moments.forcard import for_card

    model = for_card(resolve(sc.model, base))  # this card's coefficients; constants cached on disk (modelcache)
    cfg_path = resolve(sc.controller.config, base)
    cfg = load_controller(cfg_path)
    if sc.temperature_max_c is not None and "temperature" in type(cfg).model_fields:
        d = cfg.model_dump()
        d["temperature"]["ceiling_c"] = sc.temperature_max_c
        cfg = validate_controller(d, str(cfg_path))
        check_ceiling(cfg, model.card, "the scenario", field="temperature_max_c")
    else:
        check_ceiling(cfg, model.card, str(cfg_path))
    controller = make_controller(cfg, model)
    if sc.target:
        controller.set_target(dict(sc.target), t_end_h=sc.hours)
    return model, controller


def _ceiling(sc: Scenario, controller) -> float | None:
    """The scenario's ceiling, else the controller config's (a recipe has none)."""
    if sc.temperature_max_c is not None:
        return sc.temperature_max_c
    cfg = controller.cfg
    if "temperature" not in type(cfg).model_fields:  # a recipe has no temperature table
        return None
    return float(cfg.temperature.ceiling_c)


def build(sc: Scenario, base: Path, seed: int) -> ClosedLoop:
    """Fresh trial loop from a scenario and a seed (one SeedSequence spawns every generator)."""
    from .estimate.run import make_estimator
    from .physics.kinematics import kinematics
    from .plant.plant import Plant

    ss = np.random.SeedSequence(seed)
    g_plant, g_pf, g_sample = (np.random.default_rng(s) for s in ss.spawn(3))
    model, controller = _model_and_controller(sc, base)
    card = _plant_card(sc, base)
    plant = Plant(card, g_plant, sc.plant.particles)
    pf = make_estimator(sc.estimator.kind, model, g_pf, settings=sc.estimator.filter_settings())
    sp = sc.sampling
    sensor = MicrographSensor(sp.particles, sp.um_per_px, sp.noise, sp.render)
    cfg = LoopConfig(hours=sc.hours, sample_every_h=sp.every_h, temperature_reading=sp.temperature_reading,
                     ceiling_c=_ceiling(sc, controller), power_w=lambda rpm: kinematics(card, rpm).mean_power_W,
                     sample_feed=sp.feed)
    return ClosedLoop(plant, sensor, pf, controller, g_sample, cfg)


def start_truth(mill) -> dict:
    """The plant's state at t = 0 (the :data:`TRUE_KEYS` a trajectory row gives; its peak is the
    temperature then), which ``trial.json`` keeps as ``start`` for trial.png: trajectory.csv has rows
    at interval ends only. Reads the population, draws nothing.

    Parameters
    ----------
    mill : Plant
    """
    m = mill.moments()
    return {**{k: float(m[k]) for k in TRUE_KEYS if k in m}, "peak_temperature_c": float(m["temperature_c"])}


def _start(out: Path) -> dict:
    """``start`` of ``out/trial.json`` (:func:`start_truth`), or {} where there is none or it is not
    every true quantity as a finite number (a trial begun by an earlier bmctl)."""
    try:
        d = io.read_json(out / "trial.json", max_bytes=1 << 20)
    except (InputError, OSError, ValueError):
        return {}
    st = d.get("start") if isinstance(d, dict) else None
    ok = isinstance(st, dict) and all(isinstance(st.get(k), (int, float)) and not isinstance(st.get(k), bool)
                                      and np.isfinite(st[k]) for k in TRUE_KEYS)
    return st if ok else {}


def trajectory_row(rec: StepRecord) -> list:
    """The ``trajectory.csv`` row of one step."""
    st = rec.status
    row = [rec.k, rec.t_h, rec.rpm, rec.milling] + [rec.truth[k] for k in TRUE_KEYS]
    for k in EST_KEYS:
        row += [rec.estimate.get(k, float("nan")), rec.estimate.get(f"{k}_q05", float("nan")),
                rec.estimate.get(f"{k}_q95", float("nan"))]
    return row + [rec.sampled, rec.estimate.get("ess", float("nan")), rec.solve_ms, st.solver_status,
                  int(st.fallback != "none")]


def _append_row(path: Path, row: list) -> None:
    line = io.csv_text([], [row]).splitlines()[-1] + "\n"
    with open(path, "a", encoding="utf-8") as fh:
        fh.write(line)
        fh.flush()
        os.fsync(fh.fileno())


def inputs_digest(sc: Scenario, scenario_path) -> str:
    """sha256 of the scenario file and the files it names (the card, the plant's card, the
    controller, the cards' moment coefficients where present): a resume refuses a trial whose
    inputs changed since it began."""
    import hashlib

    from .moments.coeffs import coeffs_path

    base = Path(scenario_path).resolve().parent
    files = [Path(scenario_path)] + [resolve(r, base) for r in (sc.model, sc.plant.model, sc.controller.config) if r]
    files += [coeffs_path(f) for f in files[1:] if coeffs_path(f).is_file()]
    h = hashlib.sha256()
    for f in files:
        h.update(io.read_input_bytes(f))
    return h.hexdigest()


def _read_meta(path: Path) -> dict:
    if not path.exists() and not path.is_symlink():
        raise InputError(f"{arg('resume=True')}: {path} not found")
    try:
        meta = io.read_json(path, max_bytes=1 << 20)
    except InputError as exc:
        raise InputError(f"{path}: not a bmctl trial record ({str(exc).removeprefix(str(path) + ': ')})") from None
    if not isinstance(meta, dict) or not {"scenario", "seed"} <= set(meta):
        raise InputError(f"{path}: not a bmctl trial record (no scenario and seed)")
    return meta


#: trajectory columns that may hold NaN (no sample behind them)
_NAN_OK = frozenset(["ess"] + [c for c in trajectory_header() if c.endswith(("_q05", "_q95"))])


def _kept_rows(traj: Path, steps: int) -> str:
    """The header and the first ``steps`` complete rows of ``traj`` (a torn row is dropped).

    Each kept row must be one this module writes: the header of :func:`trajectory_header`,
    then rows of as many fields, numbered 0, 1, ... in ``step``, finite numbers in every field
    but ``solver_status`` (NaN allowed in ``ess`` and the bands, where no sample stands behind
    them); anything else is an InputError naming the file and the row.
    """
    try:
        text = io.read_input_bytes(traj).decode("utf-8")
    except UnicodeDecodeError:
        raise InputError(f"{traj}: not a bmctl trajectory (not UTF-8 text)") from None
    lines = [ln + "\n" for ln in text.split("\n")[:-1]]  # the text after the last newline is a torn row
    if not lines:
        raise InputError(f"{traj}: no complete header row (empty or damaged); the checkpoint needs {steps} rows")
    if len(lines) < steps + 1:
        raise InputError(f"{traj}: {len(lines) - 1} complete rows, the checkpoint needs {steps}")
    header = trajectory_header()
    rows = list(csv.reader(lines[: steps + 1]))
    if rows[0] != header:
        raise InputError(f"{traj}: row 1: not the trajectory header of this bmctl")
    status_col = header.index("solver_status")
    for i, fields in enumerate(rows[1:]):
        if len(fields) != len(header):
            raise InputError(f"{traj}: row {i + 2}: {len(fields)} fields, the header has {len(header)}")
        if fields[0] != str(i):
            raise InputError(f"{traj}: row {i + 2}: step {fields[0]!r}, expected {i}")
        for j, f in enumerate(fields):
            if j == status_col:
                continue
            try:
                v = float(f)
            except ValueError:
                raise InputError(f"{traj}: row {i + 2}: {header[j]}: not a number ({f!r})") from None
            if not math.isfinite(v) and not (math.isnan(v) and header[j] in _NAN_OK):
                raise InputError(f"{traj}: row {i + 2}: {header[j]}: not finite ({f!r})")
    return "".join(lines[: steps + 1])


#: loop tallies that appear during a run (a solver fallback's log line, the feed sampled, the binding
#: limits of the first and latest plans): a checkpoint may hold them where a fresh loop does not
GROWN_KEYS = frozenset({"log", "feed_sampled", "binding_first", "binding_last"})


def _finite_numbers(value) -> bool:
    """Whether ``value`` is None, a boolean, a finite number, short text (a plan's family name), or
    a list, table or numeric array of them."""
    if value is None or isinstance(value, bool) or (isinstance(value, str) and len(value) <= 10_000):
        return True
    if isinstance(value, dict):
        return all(_finite_numbers(v) for v in value.values())
    if isinstance(value, list):
        return all(_finite_numbers(v) for v in value)
    if isinstance(value, np.ndarray):
        return value.dtype.kind in "iuf" and bool(np.all(np.isfinite(value)))
    return isinstance(value, (int, float)) and math.isfinite(value)


def _misfit(template, value, path: str = "") -> str | None:
    """Where ``value`` (a loaded state) does not have the form of ``template`` (the state of a
    fresh loop of the same scenario), or None: the same dict keys; arrays of the same dtype kind
    and shape; numbers where numbers were, finite where they were finite; strings and booleans
    where they were; lists of such (a list may have grown: its items take the form of the first);
    where the template holds None, None or finite numbers (a not-yet-set input)."""
    where = path or "/"
    num = (int, float)
    if isinstance(template, dict):
        if not isinstance(value, dict) or not set(template) <= set(value) or set(value) - set(template) - GROWN_KEYS:
            return f"{where}: expected a table with keys {sorted(template)[:6]}"
        for k in template:
            why = _misfit(template[k], value[k], f"{path}/{k}")
            if why:
                return why
        for k in set(value) - set(template):  # a tally grown during the run: plain data
            if not _finite_numbers(value[k]):
                return f"{path}/{k}: expected plain data"
        return None
    if isinstance(template, np.ndarray):
        if not isinstance(value, np.ndarray) or value.dtype.kind != template.dtype.kind or value.shape != template.shape:
            return f"{where}: expected a {template.dtype} array of shape {template.shape}"
        if template.dtype.kind == "f" and np.all(np.isfinite(template)) and not np.all(np.isfinite(value)):
            return f"{where}: not finite"
        return None
    if isinstance(template, list):
        if not isinstance(value, list):
            return f"{where}: expected a list"
        for i, v in enumerate(value):
            t = template[i] if i < len(template) else (template[0] if template else None)
            why = _misfit(t, v, f"{path}/{i}") if template else \
                (None if _finite_numbers(v) else f"{where}/{i}: unexpected item")  # a list a fresh loop holds empty
            if why:
                return why
        return None
    if template is None:  # not set yet in a fresh loop (an input, a warm start, a flag): plain data
        return None if _finite_numbers(value) else f"{where}: expected nothing, finite numbers, booleans or text"
    if isinstance(template, bool):
        return None if isinstance(value, bool) else f"{where}: expected true or false"
    if isinstance(template, num):
        if not isinstance(value, num) or isinstance(value, bool) or (isinstance(template, int) and isinstance(value, float)):
            return f"{where}: expected a number"
        if math.isfinite(template) and not math.isfinite(value):
            return f"{where}: not finite"
        return None
    if isinstance(template, str):
        return None if isinstance(value, str) else f"{where}: expected text"
    return None


def _resume(loop: ClosedLoop, out: Path, scenario_path, seed: int) -> None:
    ckpt, traj = out / CHECKPOINT, out / "trajectory.csv"
    meta = _read_meta(out / "trial.json")
    R = arg("resume=True")
    if meta.get("campaign"):
        raise InputError(f"{R}: {out} holds a trial run as a campaign, which does not resume; run it again "
                         f"with the same {arg('seed')} into a new {arg('out')}")
    if meta.get("scenario") != str(Path(scenario_path).resolve()):
        raise InputError(f"{R}: {out} holds a trial of {meta.get('scenario')} with seed {meta.get('seed')}, "
                         f"not of {Path(scenario_path).resolve()}")
    if meta.get("seed") != seed:
        raise InputError(f"{R}: {out} holds the trial with seed {meta.get('seed')}, not {seed}; "
                         f"carry it on with {arg('seed')} {meta.get('seed')}")
    if "sha256" in meta and meta["sha256"] != inputs_digest(load_scenario(scenario_path), scenario_path):
        raise InputError(f"{R}: {scenario_path} (or the card or controller it names) changed since the trial "
                         f"in {out} began; resume with the files as they were, or start it again in a new {arg('out')}")
    if not ckpt.exists():
        raise InputError(f"{R}: {ckpt} not found")
    state = load_state(ckpt)
    why = _misfit(loop.get_state(), state)
    if why:
        raise InputError(f"{ckpt}: {why} (not a checkpoint of this trial, or damaged)")
    try:
        loop.set_state(state)
    except (KeyError, TypeError, ValueError, IndexError):
        raise InputError(f"{ckpt}: not a checkpoint of this trial (its state does not fit)") from None
    io.write_text(traj, _kept_rows(traj, loop.k))


def run_trial(scenario_path: str | Path, out: str | Path, seed: int = 0, resume: bool = False,
              max_steps: int | None = None, progress=None) -> dict:
    """Run (or resume) a trial; returns the summary dict (also written to ``summary.json``).

    Parameters
    ----------
    scenario_path : path-like
        Scenario TOML.
    out : path-like
        Output folder.
    seed : int
        Seed of the trial (plant, sampler and filter generators are spawned from it).
    resume : bool
        Carry on from ``out/checkpoint.npz``.
    max_steps : int, optional
        Stop after this many steps in this call (tests use it to simulate an interruption).
    progress : callable, optional
        Called after each step with (k, K).

    Examples
    --------
    Two steps of the open-loop lab recipe, then the rest of the batch from the checkpoint:

    >>> import tempfile
    >>> from bmctl.trial import run_trial
    >>> out = tempfile.mkdtemp()
    >>> run_trial("scenarios/trial-lab-recipe.toml", out, seed=0, max_steps=2)
    {'interrupted_at_step': 2}
    >>> summary = run_trial("scenarios/trial-lab-recipe.toml", out, seed=0, resume=True)  # doctest: +ELLIPSIS
    >>> summary["steps"]
    24
    """
    from .errors import require_whole

    seed = require_whole(seed, arg("seed"), 0)  # None drew from the OS: a trial nobody could repeat
    if max_steps is not None:
        max_steps = require_whole(max_steps, "max_steps", 0)
    sc = load_scenario(scenario_path)
    base = Path(scenario_path).resolve().parent
    out = Path(out)
    traj, ckpt = out / "trajectory.csv", out / CHECKPOINT
    if not resume and traj.exists():
        raise InputError(f"{arg('out')}: {out} already holds a trial; use {arg('resume=True')} or another folder")
    loop = build(sc, base, seed)
    check_resolvable(sc, scenario_path, loop.mill.card)  # before the folder is made
    if resume:
        _resume(loop, out, scenario_path, seed)
    else:
        out.mkdir(parents=True, exist_ok=True)
        io.write_text(out / "trial.json", json.dumps({"scenario": str(Path(scenario_path).resolve()), "seed": seed,
                                                      "sha256": inputs_digest(sc, scenario_path),
                                                      "start": start_truth(loop.mill)}))
        io.write_text(traj, ",".join(trajectory_header()) + "\n")
        save_state(ckpt, loop.get_state())
    K = loop.steps
    done_now = 0
    while not loop.done:
        if max_steps is not None and done_now >= max_steps:
            return {"interrupted_at_step": loop.k}
        _append_row(traj, trajectory_row(loop.step()))
        save_state(ckpt, loop.get_state())
        done_now += 1
        if progress is not None:
            progress(loop.k, K)
    summary = summarise(sc, loop)
    io.write_text(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    figures(sc, traj, out, loop.cfg.ceiling_c)
    return summary


def summarise(sc: Scenario, loop: ClosedLoop) -> dict:
    """The ``summary.json`` of a finished (or stopped) trial loop."""
    ceiling = loop.cfg.ceiling_c
    from .control.outputs import relative_error
    from .stats import dvalues, law_size_stats

    tm = loop.mill.moments()
    final_true = {k: tm[k] for k in TARGET_KEYS if k in tm}
    if any(k not in final_true for k in sc.target):  # volume-weighted D-values of the plant's population
        final_true.update({k: v for k, v in dvalues(loop.mill.s * 1e6).items() if k in TARGET_KEYS})
    # the same D-values through the size law of the plant's number mean and std (what the controller steers)
    law = law_size_stats(tm["s_mean_um"], tm["s_std_um"])
    final_true_law = {k: float(law[k]) for k in sc.target if k in _DVALUE_NAMES}
    err = {k: relative_error(final_true[k], v) for k, v in sc.target.items()}
    st = loop.stats
    solve = np.array(st["solve_ms"]) if st["solve_ms"] else np.array([0.0])
    return {
        "scenario": sc.scenario.name,
        "target": dict(sc.target),
        "final_true": final_true,
        "final_true_law": final_true_law,
        "final_estimate": {k: loop.est.get(k) for k in EST_KEYS},
        "final_error": err,
        "max_temperature_c": st["max_T"],
        "temperature_ceiling_c": ceiling,
        "temperature_violations": st["violations"],
        "energy_kj": st["energy_J"] / 1e3,
        "batch_h": sc.hours if loop.done else min(loop.k * loop.controller.interval_h, sc.hours),
        "solver_failures": st["solver_failures"],
        "fallbacks": st["fallbacks"],
        "median_solve_ms": float(np.median(solve)),
        "steps": loop.k,
        "feed_sampled": bool(st.get("feed_sampled", False)),
        "solver_log": st.get("log", []),
        "binding_first": st.get("binding_first", []),
        "binding_last": st.get("binding_last", []),
    }


#: the quantities of trial.png's top row; a target on another one adds a panel of its own
_TOP_KEYS = ("s_mean_um", "s_std_um", "r_mean")
#: targets that are not columns of trajectory.csv: the volume-weighted D-values of the size law
_DVALUE_NAMES = {"d50_um": "D50", "d90_um": "D90", "span": "span"}


def _final_truth(out: Path) -> dict:
    """``final_true`` of ``out/summary.json`` (written before the figures), or {} where there is none."""
    try:
        d = io.read_json(out / "summary.json", max_bytes=1 << 20)
    except (InputError, OSError, ValueError):
        return {}
    ft = d.get("final_true") if isinstance(d, dict) else None
    return ft if isinstance(ft, dict) else {}


def _series(ax, t, y, lo=None, hi=None, *, color, label, band_label="90 % band", truth=False, alpha=0.25,
            marker="o"):
    """A quantity over the interval ends and its band: a line and a shaded band, or, with a single
    interval, a marker and an error bar (a line or band of one point is not drawn)."""
    one = t.size == 1
    if not one:
        (line,) = ax.plot(t, y, "-", color=color, lw=1.5, label=label)
    elif truth:
        (line,) = ax.plot(t, y, ls="none", marker="D", ms=5, color=color, zorder=4, clip_on=False, label=label)
    else:
        (line,) = ax.plot(t, y, ls="none", marker=marker, ms=8, mfc="none", mec=color, mew=1.5, zorder=3,
                          clip_on=False, label=label)
    band = None
    if lo is None:
        return line, band
    if not one:
        band = ax.fill_between(t, lo, hi, color=color, alpha=alpha, lw=0, label=band_label)
    elif np.all(np.isfinite([lo[0], hi[0]])):
        band = ax.errorbar(t, 0.5 * (lo + hi), yerr=0.5 * np.abs(hi - lo), fmt="none", ecolor=color, elinewidth=6,
                           alpha=min(2 * alpha, 0.6), capsize=0, clip_on=False, label=band_label)
    return line, band


def _target(ax, value) -> None:
    """A point target as a dashed line, a window [lo, hi] as a band, each with its legend entry."""
    from .control.config import target_bounds

    lo, hi = target_bounds(value)
    if hi > lo:
        ax.axhspan(lo, hi, color="C3", alpha=0.2, lw=0, label="target window")
    else:
        ax.axhline(lo, color="C3", ls="--", label="target")


def _dvalue_panel(ax, col, t, key: str, final: dict) -> None:
    """A targeted D-value (or span): trajectory.csv holds none, so the estimate's is drawn from the
    Weibull size law of its mean and std (the law the filter and the controller read D-values from),
    and the plant's where summary.json gives it, at the batch end."""
    from .stats import weibull_size_stats

    name = _DVALUE_NAMES[key]
    est = np.atleast_1d(weibull_size_stats(col("est_s_mean_um"), col("est_s_std_um"))[key]).astype(float)
    _series(ax, t, est, color="C0",
            label=f"estimate: Weibull law of its mean & std\n(trajectory.csv: no {name}, no band)")
    v = final.get(key)
    if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v):
        ax.plot([t[-1]], [v], ls="none", marker="D", ms=6, color="k", zorder=4, clip_on=False,
                label="plant at batch end (summary.json;\nnot recorded per interval)")


def _legend_above_data(ax, *handles_labels):
    """The legend at the top of ``ax``, the y range raised so that no data lie under it (two
    columns where they fit the panel's width, else smaller type, else one column)."""
    r = ax.figure.canvas.get_renderer()
    axbox = ax.get_window_extent(r)
    for ncol, size in ((2, 8), (2, 7), (1, 8)):
        leg = ax.legend(*handles_labels, fontsize=size, ncol=ncol, loc="upper center", borderaxespad=0.3,
                        framealpha=0.9)
        box = leg.get_window_extent(r)
        if box.width <= 0.98 * axbox.width:
            break
    frac = min(box.height / axbox.height + 0.04, 0.75)  # share of the panel's height the legend takes
    lo, hi = ax.get_ylim()
    ax.set_ylim(lo, hi + (hi - lo) * frac / (1 - frac))
    return leg


def figures(sc: Scenario, traj: Path, out: Path, ceiling: float | None) -> None:
    """``trial.png``: the moments and each targeted quantity with the truth, the estimate's 90 % band
    and the target value or window; rpm and rests; temperature; the estimated γ and δ factors.

    Every time axis spans 0 to the batch end. The plant's curves start at t = 0 where ``trial.json``
    holds its state then (:func:`start_truth`; trajectory.csv has rows at interval ends only); the
    estimate's at the first interval's end. A trial of one interval draws its single estimate with
    markers and its bands as error bars. A D-value target, which trajectory.csv has no column for, is drawn from the
    estimate's mean and std, with the plant's final value of ``summary.json`` where present.
    """
    from .io import pyplot
    from .plots import quantity_label

    plt = pyplot()
    data = np.genfromtxt(traj, delimiter=",", names=True, dtype=None, encoding="utf-8")

    def col(name: str) -> np.ndarray:
        return np.atleast_1d(data[name]).astype(float)

    t = col("t_h")
    start = _start(out)
    t_truth = np.concatenate([[0.0], t]) if start else t  # the plant's state at t = 0 where trial.json has it

    def truth(name: str) -> np.ndarray:
        return np.concatenate([[start[name]], col(f"true_{name}")]) if start else col(f"true_{name}")

    t_end = float(t[-1])  # the batch end (the last row is written at the end of the last interval)
    t0 = np.concatenate([[0.0], t[:-1]])  # each interval's start (rows are written at interval ends)
    one = t.size == 1
    top = list(_TOP_KEYS) + [k for k in sc.target if k not in _TOP_KEYS]
    final = _final_truth(out) if any(k in _DVALUE_NAMES for k in top) else {}
    fig = plt.figure(figsize=(14 * len(top) / 3, 7))
    # fixed margins: tight_layout would draw the figure once more only to measure it
    gs = fig.add_gridspec(2, 1, left=0.055 * 3 / len(top), right=1 - 0.035 * 3 / len(top), bottom=0.075,
                          top=0.91, hspace=0.32)
    top_axes = [fig.add_subplot(g) for g in gs[0].subgridspec(1, len(top), wspace=0.36)]
    axes = [fig.add_subplot(g) for g in gs[1].subgridspec(1, 3, wspace=0.36)]
    for i, (ax, k) in enumerate(zip(top_axes, top)):
        if k in _DVALUE_NAMES:
            _dvalue_panel(ax, col, t, k, final)
        else:
            _series(ax, t_truth, truth(k), color="k", label="plant (truth)", truth=True)
            _series(ax, t, col(f"est_{k}"), col(f"est_{k}_q05"), col(f"est_{k}_q95"), color="C0", label="estimate")
        if k in sc.target:
            _target(ax, sc.target[k])
        ax.set_title(quantity_label(k)), ax.set_xlabel("batch time (h)"), ax.set_ylabel(quantity_label(k))
        ax.set_xlim(0, t_end), ax.grid(alpha=0.3)
        if i == 0 or k in sc.target or k in _DVALUE_NAMES:
            _legend_above_data(ax)
    ax = axes[0]
    rpm = col("rpm")
    ax.step(np.append(t0, t_end), np.append(rpm, rpm[-1]), where="post", color="C2")  # each speed over its interval
    ax.set_ylabel("rpm"), ax.set_xlabel("batch time (h)"), ax.set_title("rpm (bars: rest share)"), ax.grid(alpha=0.3)
    ax.set_ylim(0, max(float(np.max(rpm)), 1.0) * 1.1)
    ax2 = ax.twinx()
    ax2.bar(0.5 * (t0 + t), 1 - col("milling"), width=0.9 * (t - t0), color="C7", alpha=0.4)  # one bar per interval
    ax2.set_ylim(0, 1), ax2.set_ylabel("rest fraction")
    ax.set_xlim(0, t_end)
    ax = axes[1]
    peak = col("true_peak_temperature_c")
    ax.hlines(peak, t0, t, color="C3", lw=2, label="plant, peak in each interval")
    ax.plot(t_truth, truth("temperature_c"), "C3o", ms=5 if one else 3, alpha=0.6, clip_on=False,
            label="plant at interval ends" + (" and t = 0" if start else ""))
    ax.plot(t, col("est_temperature_c"), "C0--", marker="o" if one else None, mfc="none", clip_on=not one,
            label="estimate at interval ends")
    if ceiling is not None:
        ax.axhline(ceiling, color="k", ls=":", label=f"ceiling {ceiling:g} °C")
    ax.set_title(f"vial temperature (highest {np.max(peak):.1f} °C)"), ax.set_ylabel("vial temperature (°C)")
    ax.set_xlabel("batch time (h)"), ax.set_xlim(0, t_end), ax.grid(alpha=0.3)
    _legend_above_data(ax)
    ax = axes[2]
    handles, labels = [], []
    for name, c, m in (("gamma_mult", "C0", "o"), ("delta_mult", "C1", "s")):
        line, band = _series(ax, t, col(f"est_{name}"), col(f"est_{name}_q05"), col(f"est_{name}_q95"), color=c,
                             label=quantity_label(name), alpha=0.2, marker=m)
        handles.append(line if band is None else (band, line))  # one entry: the estimate over its band
        labels.append(quantity_label(name) + ("" if band is None else " (band: 90 %)"))
    ax.set_title("estimated bonding γ and fracture δ factors"), ax.set_ylabel("factor relative to the card (1 = card)")
    ax.set_xlabel("batch time (h)"), ax.set_xlim(0, t_end), ax.grid(alpha=0.3)
    _legend_above_data(ax, handles, labels)
    fig.suptitle(f"{sc.scenario.name}: {sc.scenario.description}")
    io.savefig(fig, out / "trial.png", dpi=110)
