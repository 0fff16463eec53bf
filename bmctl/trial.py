"""Closed-loop trials: plant -> micrograph sampler -> particle filter -> controller -> plant.

Written step by step to disk so that a killed trial loses nothing and resumes:

* ``trajectory.csv`` — one row per control interval, appended and flushed (fsync) each step;
* ``checkpoint.pkl`` — the full state after the last written row (plant, filter, sampler and
  controller, their random generators included), replaced atomically each step;
* ``summary.json`` and figures when the trial ends.

Resuming (``--resume DIR``) truncates ``trajectory.csv`` to the checkpoint's rows and carries on;
with the same seed the result is identical to an uninterrupted run.
"""

from __future__ import annotations

import json
import math
import os
import pickle
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import io
from .config import ModelCard, load_card, with_factors
from .errors import InputError
from .scenario import TARGET_KEYS, Scenario, load_scenario, resolve

TRUE_KEYS = ("s_mean_um", "s_std_um", "r_mean", "r_std", "temperature_c")
EST_KEYS = ("s_mean_um", "s_std_um", "r_mean", "r_std", "temperature_c", "gamma_mult", "delta_mult")


def trajectory_header() -> list[str]:
    h = ["step", "t_h", "rpm", "milling"] + [f"true_{k}" for k in TRUE_KEYS]
    for k in EST_KEYS:
        h += [f"est_{k}", f"est_{k}_q05", f"est_{k}_q95"]
    return h + ["sampled", "ess", "solve_ms", "solver_status", "fallback"]


@dataclass
class TrialState:
    """Everything a trial needs to carry on after step ``k``."""

    k: int
    plant: object
    pf: object
    controller: object
    sample_rng: np.random.Generator
    u_prev: tuple[float, float] | None
    est: dict
    next_sample_h: float
    stats: dict = field(default_factory=dict)


def _plant_card(sc: Scenario, base: Path) -> ModelCard:
    card = load_card(resolve(sc.plant.model or sc.model, base))
    return with_factors(card, sc.plant.gamma_factor, sc.plant.delta_factor)


def _model_and_controller(sc: Scenario, base: Path):
    """The moment model and the controller of a scenario (no random state: rebuilt on resume)."""
    from .control import make_controller
    from .control.config import load_controller, validate_controller
    from .moments.model import make_moment_model

    model = make_moment_model(resolve(sc.model, base))
    cfg_path = resolve(sc.controller.config, base)
    cfg = load_controller(cfg_path)
    if sc.temperature_max_c is not None and hasattr(cfg, "temperature"):
        d = cfg.model_dump()
        d["temperature"]["ceiling_c"] = sc.temperature_max_c
        cfg = validate_controller(d, str(cfg_path))
    controller = make_controller(cfg, model)
    if sc.target and hasattr(controller, "set_target"):
        controller.set_target(dict(sc.target), t_end_h=sc.hours)
    return model, controller


def build(sc: Scenario, base: Path, seed: int) -> TrialState:
    """Fresh trial state from a scenario and a seed (one SeedSequence spawns every generator)."""
    from .estimate import FilterSettings, ParticleFilter
    from .plant.plant import Plant

    ss = np.random.SeedSequence(seed)
    g_plant, g_pf, g_sample = (np.random.default_rng(s) for s in ss.spawn(3))
    model, controller = _model_and_controller(sc, base)
    plant = Plant(_plant_card(sc, base), g_plant, sc.plant.particles)
    pf = ParticleFilter(model, g_pf, FilterSettings(n_particles=sc.estimator.particles))
    return TrialState(k=0, plant=plant, pf=pf, controller=controller, sample_rng=g_sample, u_prev=None,
                      est=pf.estimate().as_dict(), next_sample_h=sc.sampling.every_h,
                      stats={"solver_failures": 0, "fallbacks": 0, "energy_J": 0.0, "max_T": plant.temperature_C,
                             "violations": 0, "solve_ms": []})


def _sample(sc: Scenario, state: TrialState):
    from .measure.sampler import micrograph_sample

    p = state.plant
    s_um, r = p.s * 1e6, p.r
    tab = micrograph_sample(s_um, r, sc.sampling.particles, state.sample_rng, um_per_px=sc.sampling.um_per_px,
                            noise=sc.sampling.noise, render=sc.sampling.render)
    return np.asarray(tab.s_um), np.asarray(tab.r)


def _x_est(est: dict) -> tuple[np.ndarray, np.ndarray]:
    x = np.array([est["s_mean_um"], est["s_std_um"], est["r_mean"], est["r_std"], est["temperature_c"],
                  est.get("hardening", 0.0)])
    return x, np.array([est.get("gamma_mult", 1.0), est.get("delta_mult", 1.0)])


def step(sc: Scenario, state: TrialState, ceiling: float | None) -> list:
    """Advance the trial by one control interval; returns the trajectory row."""
    from .plant.kinematics import kinematics

    interval = state.controller.interval_h
    t_h = state.k * interval
    dt = min(interval, sc.hours - t_h)
    x, p = _x_est(state.est)
    t0 = time.perf_counter()
    if getattr(state.controller, "n_scen", 1) > 1:  # scenario MPC: the filter's spread as extra scenarios
        from .control.robust import filter_scenarios

        plan = state.controller.plan(x, t_h, p=p, u_prev=state.u_prev,
                                     scenarios=filter_scenarios(state.est, state.controller.n_scen - 1))
    else:
        plan = state.controller.plan(x, t_h, p=p, u_prev=state.u_prev)
    st = plan.status
    solve_ms = st.solve_ms if st.solve_ms else (time.perf_counter() - t0) * 1e3
    rpm, milling = (float(v) for v in plan.u_apply)
    status = st.solver_status
    fallback = st.fallback != "none"
    state.stats["solve_ms"].append(solve_ms)
    state.stats["fallbacks"] += int(fallback)
    state.stats["solver_failures"] += int(not st.success)
    if fallback or not st.success:
        state.stats.setdefault("log", []).append(f"t={t_h:g} h: {st.line()}")

    plant = state.plant
    card = plant.card
    # finer plant steps to watch the temperature within the interval
    n_sub = max(1, int(math.ceil(dt / 0.05)))
    mill_h = dt * milling
    for j in range(n_sub):
        a, b = j * dt / n_sub, (j + 1) * dt / n_sub
        m = max(0.0, min(b, mill_h) - a) / (b - a)
        plant.advance(rpm, b - a, milling=m)
        state.stats["max_T"] = max(state.stats["max_T"], plant.temperature_C)
        if ceiling is not None and plant.temperature_C > ceiling + 1e-9:
            state.stats["violations"] += 1
    state.stats["energy_J"] += kinematics(card, rpm).mean_power_W * mill_h * 3600.0
    state.pf.predict((rpm, milling), dt)
    t_new = t_h + dt
    sampled = 0
    if t_new >= state.next_sample_h - 1e-9 or t_new >= sc.hours - 1e-9:
        s_um, r = _sample(sc, state)
        T_read = plant.temperature_C if sc.sampling.temperature_reading else None
        est = state.pf.update(s_um, r, temperature_c=T_read)
        state.next_sample_h += sc.sampling.every_h
        sampled = 1
    else:
        est = state.pf.estimate()
    state.est = est.as_dict()
    state.u_prev = (rpm, milling)
    tm = plant.moments()
    row = [state.k, t_new, rpm, milling] + [tm[k] for k in TRUE_KEYS]
    for k in EST_KEYS:
        row += [state.est.get(k, float("nan")), state.est.get(f"{k}_q05", float("nan")),
                state.est.get(f"{k}_q95", float("nan"))]
    row += [sampled, state.est.get("ess", float("nan")), solve_ms, status, int(fallback)]
    state.k += 1
    return row


def _append_row(path: Path, row: list) -> None:
    line = io.csv_text([], [row]).splitlines()[-1] + "\n"
    with open(path, "a") as fh:
        fh.write(line)
        fh.flush()
        os.fsync(fh.fileno())


def _picklable(value) -> bool:
    if _has_casadi(value):
        return False
    try:
        pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL)
        return True
    except Exception:  # casadi objects, compiled solvers: rebuilt on resume
        return False


def _has_casadi(value) -> bool:
    if type(value).__module__.startswith("casadi"):
        return True
    if isinstance(value, dict):
        return any(_has_casadi(v) for v in value.values())
    if isinstance(value, (list, tuple)):
        return any(_has_casadi(v) for v in value)
    return False


def _save_checkpoint(path: Path, state: TrialState) -> None:
    """Pickle the trial state; the controller and the moment model travel as their plain data only.

    Compiled casadi functions and solvers are deterministic functions of the scenario, so they
    are rebuilt on resume; the controller's warm-start data (previous plan, multipliers, ...)
    is kept.
    """
    ctrl, model = state.controller, state.pf.model
    ctrl_data = {k: v for k, v in vars(ctrl).items() if k != "model" and _picklable(v)}
    state.controller, state.pf.model = None, None
    try:
        with io.atomic_path(path, suffix=".pkl") as tmp:
            with open(tmp, "wb") as fh:
                pickle.dump({"state": state, "controller": ctrl_data}, fh, protocol=pickle.HIGHEST_PROTOCOL)
    finally:
        state.controller, state.pf.model = ctrl, model


def _load_checkpoint(path: Path, sc: Scenario, base: Path) -> TrialState:
    with open(path, "rb") as fh:
        data = pickle.load(fh)
    state: TrialState = data["state"]
    model, controller = _model_and_controller(sc, base)
    vars(controller).update(data["controller"])
    state.controller, state.pf.model = controller, model
    return state


def _ceiling(sc: Scenario, state: TrialState) -> float | None:
    if sc.temperature_max_c is not None:
        return sc.temperature_max_c
    temp = getattr(getattr(state.controller, "cfg", None), "temperature", None)
    return None if temp is None else float(temp.ceiling_c)


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
        Carry on from ``out/checkpoint.pkl``.
    max_steps : int, optional
        Stop after this many steps in this call (tests use it to simulate an interruption).
    progress : callable, optional
        Called after each step with (k, K).
    """
    sc = load_scenario(scenario_path)
    base = Path(scenario_path).resolve().parent
    out = Path(out)
    traj, ckpt = out / "trajectory.csv", out / "checkpoint.pkl"
    if resume:
        if not ckpt.exists():
            raise InputError(f"--resume: {ckpt} not found")
        state = _load_checkpoint(ckpt, sc, base)
        meta = json.loads((out / "trial.json").read_text())
        if meta.get("seed") != seed or meta.get("scenario") != str(Path(scenario_path).resolve()):
            raise InputError(f"--resume: {out} holds a trial of {meta.get('scenario')} with seed {meta.get('seed')}")
        lines = traj.read_text().splitlines(keepends=True)[: state.k + 1]
        io.write_text(traj, "".join(lines))
    else:
        if traj.exists():
            raise InputError(f"--out: {out} already holds a trial; use --resume or another folder")
        state = build(sc, base, seed)
        out.mkdir(parents=True, exist_ok=True)
        io.write_text(out / "trial.json", json.dumps({"scenario": str(Path(scenario_path).resolve()), "seed": seed}))
        io.write_text(traj, ",".join(trajectory_header()) + "\n")
        _save_checkpoint(ckpt, state)
    ceiling = _ceiling(sc, state)
    K = int(math.ceil(sc.hours / state.controller.interval_h - 1e-9))
    done_now = 0
    while state.k < K:
        if max_steps is not None and done_now >= max_steps:
            return {"interrupted_at_step": state.k}
        row = step(sc, state, ceiling)
        _append_row(traj, row)
        _save_checkpoint(ckpt, state)
        done_now += 1
        if progress is not None:
            progress(state.k, K)
    summary = summarise(sc, state, ceiling)
    io.write_text(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    figures(sc, traj, out, ceiling)
    return summary


def summarise(sc: Scenario, state: TrialState, ceiling: float | None) -> dict:
    tm = state.plant.moments()
    from .control.outputs import relative_error
    from .stats import dvalues

    final_true = {k: tm[k] for k in TARGET_KEYS if k in tm}
    if any(k not in final_true for k in sc.target):  # volume-weighted D-values of the plant's population
        final_true.update({k: v for k, v in dvalues(state.plant.s * 1e6).items() if k in TARGET_KEYS})
    err = {k: relative_error(final_true[k], v) for k, v in sc.target.items()}
    st = state.stats
    solve = np.array(st["solve_ms"]) if st["solve_ms"] else np.array([0.0])
    return {
        "scenario": sc.scenario.name,
        "target": dict(sc.target),
        "final_true": final_true,
        "final_estimate": {k: state.est.get(k) for k in EST_KEYS},
        "final_error": err,
        "max_temperature_c": st["max_T"],
        "temperature_ceiling_c": ceiling,
        "temperature_violations": st["violations"],
        "energy_kj": st["energy_J"] / 1e3,
        "batch_h": min(state.k * state.controller.interval_h, sc.hours),
        "solver_failures": st["solver_failures"],
        "fallbacks": st["fallbacks"],
        "median_solve_ms": float(np.median(solve)),
        "steps": state.k,
        "solver_log": st.get("log", []),
    }


def figures(sc: Scenario, traj: Path, out: Path, ceiling: float | None) -> None:
    """Moments with target and estimate bands; rpm and rests; temperature."""
    from .io import pyplot

    plt = pyplot()

    from .plots import quantity_label

    data = np.genfromtxt(traj, delimiter=",", names=True, dtype=None, encoding="utf-8")
    t = np.atleast_1d(data["t_h"])
    fig, axes = plt.subplots(2, 3, figsize=(14, 7))
    for ax, k in zip(axes[0], ("s_mean_um", "s_std_um", "r_mean")):
        ax.plot(t, data[f"true_{k}"], "k-", lw=1.5, label="plant (truth)")
        ax.plot(t, data[f"est_{k}"], "C0-", label="estimate")
        ax.fill_between(t, data[f"est_{k}_q05"], data[f"est_{k}_q95"], color="C0", alpha=0.25, label="90 % band")
        if k in sc.target:
            from .control.config import target_bounds

            lo_, hi_ = target_bounds(sc.target[k])
            ax.axhspan(lo_, hi_, color="C3", alpha=0.2) if hi_ > lo_ else ax.axhline(lo_, color="C3", ls="--",
                                                                                   label="target")
        ax.set_title(quantity_label(k)), ax.set_xlabel("t (h)"), ax.set_ylabel(quantity_label(k)), ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=8)
    ax = axes[1][0]
    ax.step(t, data["rpm"], where="pre", color="C2")
    ax.set_ylabel("rpm"), ax.set_xlabel("t (h)"), ax.set_title("rpm (bars: rest share)"), ax.grid(alpha=0.3)
    ax2 = ax.twinx()
    width = float(np.diff(t).min()) if t.size > 1 else 0.5
    ax2.bar(t - width / 2, 1 - data["milling"], width=width * 0.9, color="C7", alpha=0.4)
    ax2.set_ylim(0, 1), ax2.set_ylabel("rest fraction")
    ax = axes[1][1]
    ax.plot(t, data["true_temperature_c"], "C3-", label="plant")
    ax.plot(t, data["est_temperature_c"], "C0--", label="estimate")
    if ceiling is not None:
        ax.axhline(ceiling, color="k", ls=":", label="ceiling")
    ax.set_title("vial temperature"), ax.set_ylabel("vial temperature (°C)"), ax.set_xlabel("t (h)")
    ax.legend(fontsize=8), ax.grid(alpha=0.3)
    ax = axes[1][2]
    ax.plot(t, data["est_gamma_mult"], label=quantity_label("gamma_mult"))
    ax.plot(t, data["est_delta_mult"], label=quantity_label("delta_mult"))
    ax.fill_between(t, data["est_gamma_mult_q05"], data["est_gamma_mult_q95"], alpha=0.2)
    ax.fill_between(t, data["est_delta_mult_q05"], data["est_delta_mult_q95"], alpha=0.2)
    ax.set_title("estimated bonding γ and fracture δ factors"), ax.set_ylabel("factor relative to the card (1 = card)")
    ax.set_xlabel("t (h)"), ax.legend(fontsize=8), ax.grid(alpha=0.3)
    fig.suptitle(f"{sc.scenario.name}: {sc.scenario.description}")
    fig.tight_layout()
    io.savefig(fig, out / "trial.png", dpi=110)
