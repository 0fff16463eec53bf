"""Offline design: the MPC problem solved once over a whole batch from the card's initial state,
turned into an open-loop rpm/rest schedule (the ``[[segment]] hours, rpm`` format that
``bmctl simulate --schedule`` reads), the predicted moments and a figure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io import csv_text, write_text
from .base import Plan, applied_input_guarded, interval_peaks, schedule_segments
from .config import TARGET_KEYS, MPCConfig

#: the design is one cold solve over the whole batch (exact Hessian): at least this many iterations
DESIGN_MIN_ITER = 300


@dataclass
class Design:
    """A designed batch.

    Attributes
    ----------
    target : dict
    hours : float
    interval_h : float
    U : ndarray, (K, 2)
        Applied (rpm, milling) per interval: whole rpm, whole minutes of milling.
    X : ndarray, (K + 1, 6)
        Moment-model prediction under ``U`` (from the card's initial state).
    t_peak_c : ndarray, (K,)
    segments : list of (hours, rpm)
        The schedule (rpm 0 = rest), trimmed to ``hours``.
    plan : Plan
        The MPC solution it came from (continuous milling fractions, solver status).
    """

    card_name: str
    controller_name: str
    target: dict
    hours: float
    interval_h: float
    ceiling_c: float
    U: np.ndarray
    X: np.ndarray
    t_peak_c: np.ndarray
    segments: list
    plan: Plan

    @property
    def times_h(self) -> np.ndarray:
        return np.minimum(self.interval_h * np.arange(self.U.shape[0] + 1), self.hours)

    milling_h: float = 0.0
    energy_kWh: float = 0.0  # dissipated in the vial: P_max (rpm / rpm_max)^3 x milling hours


def design_schedule(model, target: dict, hours: float, cfg: MPCConfig, p=None) -> Design:
    """Solve the MPC problem over ``hours`` from ``model.x0()`` and round it into a schedule.

    Parameters
    ----------
    model : MomentModel
    target : dict
        {moment: value} on any subset of s_mean_um, s_std_um, r_mean, r_std.
    hours : float
        Batch length (> 0); the horizon is ``ceil(hours / interval_h)`` intervals.
    cfg : MPCConfig
    p : array_like, optional
        (gamma_mult, delta_mult); default (1, 1).
    """
    from .mpc import MPCController

    if not (isinstance(hours, (int, float)) and math.isfinite(hours) and hours > 0):
        raise InputError(f"hours: must be a finite number > 0 (got {hours})")
    if not target:
        raise InputError("target: names no moment")
    dt = cfg.interval_h
    K = max(1, int(math.ceil(hours / dt - 1e-9)))
    solver = cfg.solver.model_copy(update={"max_iter": max(cfg.solver.max_iter, DESIGN_MIN_ITER),
                                           "cold_hessian": "exact"})
    cfg_d = cfg.model_copy(update={"horizon": K, "batch_hours": float(hours), "solver": solver})
    ctrl = MPCController(cfg_d, model, dict(target))
    x0 = model.x0()
    pp = model.p0() if p is None else np.asarray(p, dtype=float)
    plan = ctrl.plan(x0, 0.0, pp, None)
    on = cfg.onoff
    U = np.zeros((K, 2))
    X = [x0]
    for k in range(K):
        u = np.array([round(float(plan.u[k, 0])), plan.u[k, 1]])
        a = applied_input_guarded(model, X[-1], u, dt, cfg.temperature.ceiling_c, on.round_minutes,
                                  on.mode == "binary")
        U[k] = a
        X.append(model.simulate(X[-1], a[None, :], dt, pp)[-1])
    X = np.array(X)
    Tpk = interval_peaks(model, X, U, dt)
    segs = _trim(schedule_segments(U, dt), hours)
    c = model.const
    energy = float(np.sum(c.power_max_W * (U[:, 0] / c.rpm_max) ** 3 * U[:, 1] * dt) / 1000.0)
    return Design(model.card.card.name, cfg.name, dict(target), float(hours), dt, cfg.temperature.ceiling_c,
                  U, X, Tpk, segs, plan, float(np.sum(U[:, 1]) * dt), energy)


def _trim(segs, hours):
    out, t = [], 0.0
    for h, r in segs:
        if t >= hours - 1e-9:
            break
        h = min(h, hours - t)
        out.append((h, r))
        t += h
    while out and out[-1][1] == 0.0 and len(out) > 1:  # a trailing rest does nothing to the powder
        out.pop()
    return out


def schedule_toml(d: Design) -> str:
    """The schedule as TOML text (``bmctl simulate --schedule`` format)."""
    tgt = ", ".join(f"{k} = {v:g}" for k, v in d.target.items())
    last = d.X[-1]
    lines = [
        f"# Designed by `bmctl design` for {d.card_name}: target {tgt} at {d.hours:g} h",
        f"# controller {d.controller_name or 'mpc'}; solver {d.plan.status.solver_status}, "
        f"{d.plan.status.iterations} it, {d.plan.status.solve_ms:.0f} ms",
        f"# predicted (moment model): s mean {last[0]:.2f} um, s std {last[1]:.2f} um, r mean {last[2]:.4f}, "
        f"r std {last[3]:.4f}; peak vial T {np.max(d.t_peak_c):.1f} C (ceiling {d.ceiling_c:g} C)",
        "# rpm 0 = rest; milling times are whole minutes",
        f'name = "design-{d.card_name}"',
    ]
    for h, r in d.segments:
        lines += ["", "[[segment]]", f"hours = {h:.10g}   # {h * 60:.0f} min", f"rpm = {r:g}"]
    return "\n".join(lines) + "\n"


def predicted_csv(d: Design) -> str:
    header = ["t_h", "rpm", "milling", "t_peak_c", "s_mean_um", "s_std_um", "r_mean", "r_std", "temperature_c",
              "hardening"] + [f"target_{k}" for k in d.target]
    rows = []
    t = d.times_h
    for k in range(d.X.shape[0]):
        u = d.U[k] if k < d.U.shape[0] else (float("nan"), float("nan"))
        tp = d.t_peak_c[k] if k < d.U.shape[0] else float("nan")
        rows.append([float(t[k]), float(u[0]), float(u[1]), float(tp), *map(float, d.X[k])] +
                    [float(v) for v in d.target.values()])
    return csv_text(header, rows)


def design_figure(d: Design, path: Path) -> None:
    from ..io import pyplot, savefig

    from ..plots import quantity_label

    plt = pyplot()

    t = d.times_h
    fig, axes = plt.subplots(2, 2, figsize=(11, 6.5), sharex=True)
    ax = axes[0, 0]
    ax.step(t[:-1], d.U[:, 0], where="post", color="tab:blue", label="rpm")
    ax.set_ylabel("rpm (while milling)")
    ax2 = ax.twinx()
    ax2.bar(t[:-1], d.U[:, 1], width=d.interval_h, align="edge", alpha=0.25, color="tab:gray", label="milling")
    ax2.set_ylim(0, 1.05)
    ax2.set_ylabel("milling fraction")
    ax.set_title("schedule (bars: share of each interval spent milling)")
    ax.grid(alpha=0.3)
    for ax, keys, lab in ((axes[0, 1], ("s_mean_um", "s_std_um"), "size s (µm, by number)"),
                          (axes[1, 0], ("r_mean", "r_std"), "irregularity r = 1 − πs/L (0 = round)")):
        for key in keys:
            i = TARGET_KEYS.index(key)
            line, = ax.plot(t, d.X[:, i], marker="o", ms=3, label=quantity_label(key))
            if key in d.target:
                ax.axhline(d.target[key], color=line.get_color(), ls="--", lw=1, label=f"target: {quantity_label(key)}")
        ax.set_ylabel(lab)
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    ax = axes[1, 1]
    ax.plot(t, d.X[:, 4], color="tab:red", marker="o", ms=3, label="T at interval ends")
    ax.step(t[:-1], d.t_peak_c, where="post", color="tab:orange", label="peak T per interval")
    ax.axhline(d.ceiling_c, color="k", ls="--", lw=1, label="ceiling")
    ax.set_ylabel("vial temperature (°C)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("t (h)")
    fig.suptitle(f"{d.card_name}: designed schedule (moment-model prediction)")
    fig.tight_layout()
    savefig(fig, path, dpi=110, bbox_inches="tight")


def write_design(d: Design, out: Path) -> list[Path]:
    """Write schedule.toml, predicted.csv and design.png under ``out`` (atomically)."""
    out = Path(out)
    paths = [out / "schedule.toml", out / "predicted.csv", out / "design.png"]
    write_text(paths[0], schedule_toml(d))
    write_text(paths[1], predicted_csv(d))
    design_figure(d, paths[2])
    return paths
