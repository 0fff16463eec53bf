"""Offline design: the MPC problem solved once over a whole batch from the card's initial state,
turned into an open-loop rpm/rest schedule (the ``[[segment]] hours, rpm`` format that
``bmctl simulate --schedule`` reads), the predicted moments and a figure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io import csv_text, write_text
from .config import TARGET_KEYS, MPCConfig, format_target



@dataclass
class Design:
    """A designed batch: a phase-pattern schedule (:mod:`bmctl.control.pattern`) and its prediction.

    Attributes
    ----------
    target : dict
        {key: point or (lo, hi)}.
    hours : float
        Batch length designed for (the schedule may end earlier: min_time).
    U : ndarray, (K, 2)
        (rpm, milling 1/0) per segment.
    X : ndarray, (K + 1, 6)
        Moment-model states at the segment ends (exact for the model).
    t_peak_c : ndarray, (K,)
        Highest vial temperature per segment.
    segments : list of (hours, rpm)
    result : PatternResult
    reach : Reach
    pareto : list of PatternResult
        The batch-length sweep behind min_time / min_energy (empty for "target").
    """

    card_name: str
    controller_name: str
    target: dict
    hours: float
    ceiling_c: float
    U: np.ndarray
    X: np.ndarray
    t_peak_c: np.ndarray
    segments: list
    result: object
    reach: object
    objective: str = "target"
    pareto: list = field(default_factory=list)

    @property
    def times_h(self) -> np.ndarray:
        return np.concatenate([[0.0], np.cumsum([h for h, _ in self.segments])])

    @property
    def milling_h(self) -> float:
        return self.result.milling_h

    @property
    def energy_kWh(self) -> float:  # dissipated in the vial: P_max (rpm / rpm_max)^3 x milling hours
        return self.result.energy_kWh


def design_schedule(model, target: dict, hours: float, cfg: MPCConfig, p=None, objective: str | None = None,
                    method: str | None = None) -> Design:
    """Design a phase-pattern schedule over ``hours`` from ``model.x0()`` under the mill's limits.

    Parameters
    ----------
    model : MomentModel
    target : dict
        {key: point or (lo, hi)}, keys from :data:`TARGET_KEYS`.
    hours : float
        Batch length (> 0).
    cfg : MPCConfig
        Bounds, ceiling, weights, ``[mill]`` and ``[objective]``.
    p : array_like, optional
        (gamma_mult, delta_mult); default (1, 1).
    objective : str, optional
        "target", "min_time" or "min_energy" (default: ``cfg.objective.kind``).
    method : str, optional
        "relax-round" or "bonmin" (default: ``cfg.objective.integer_method``).
    """
    from .pattern import PatternDesigner
    from .reach import reachability

    if not (isinstance(hours, (int, float)) and math.isfinite(hours) and hours > 0):
        raise InputError(f"hours: must be a finite number > 0 (got {hours})")
    if not target:
        raise InputError("target: names no moment")
    obj = objective or cfg.objective.kind
    meth = method or cfg.objective.integer_method
    tol = cfg.objective.tolerance
    pareto = []
    if obj == "target":
        res = PatternDesigner(model, hours, cfg, target, p).solve(meth)
    else:
        for frac in sorted(cfg.objective.sweep):
            pareto.append(PatternDesigner(model, hours * frac, cfg, target, p).solve(meth))
        ok = [r for r in pareto if r.error <= tol]
        if not ok:
            res = min(pareto, key=lambda r: r.error)
        elif obj == "min_time":
            res = min(ok, key=lambda r: (r.hours, r.energy_kWh))
        else:
            res = min(ok, key=lambda r: (r.energy_kWh, r.hours))
    reach = reachability(model, target, hours, cfg, p, result=res if res.hours >= hours - 1e-9 else None) \
        if res.error > tol else reachability(model, target, hours, cfg, p, result=res)
    segs = res.segments
    U = np.array([[r, 1.0 if r > 0 else 0.0] for _, r in segs]).reshape(-1, 2)
    X = np.array(res.seg_states)
    Tpk = np.maximum(X[:-1, 4], X[1:, 4]) if len(segs) else np.zeros(0)
    return Design(model.card.card.name, cfg.name, dict(target), float(res.hours), cfg.temperature.ceiling_c,
                  U, X, Tpk, segs, res, reach, obj, pareto)


def pareto_table(d: Design) -> str:
    """The batch-length sweep as a markdown table: time, energy, final error, switches, peak T."""
    rows = ["| batch h | milling h | energy kWh | final error % | switches | peak T °C |", "|---|---|---|---|---|---|"]
    for r in d.pareto:
        rows.append(f"| {r.hours:.2f} | {r.milling_h:.2f} | {r.energy_kWh:.3f} | {100 * r.error:.2f} | "
                    f"{r.switches} | {r.peak_c:.1f} |")
    return "\n".join(rows)


def schedule_toml(d: Design) -> str:
    """The schedule as TOML text (``bmctl simulate --schedule`` format)."""
    tgt = ", ".join(f"{k} = {format_target(v)}" for k, v in d.target.items())
    last = d.X[-1]
    r = d.result
    lines = [
        f"# Designed by `bmctl design` for {d.card_name}: target {tgt} at {d.hours:g} h (objective {d.objective})",
        f"# controller {d.controller_name or 'mpc'}; {r.method}: {r.status}, {r.solve_s:.1f} s; "
        f"{r.switches} on/off switches; predicted D50 {r.outputs['d50_um']:.2f} µm, error {100 * r.error:.2f} %",
        f"# predicted (moment model): s mean {last[0]:.2f} µm, s std {last[1]:.2f} µm, r mean {last[2]:.4f}, "
        f"r std {last[3]:.4f}; peak vial T {np.max(d.t_peak_c):.1f} °C (ceiling {d.ceiling_c:g} °C)",
        "# rpm 0 = rest; milling times are whole minutes",
        f'name = "design-{d.card_name}"',
    ]
    for h, r in d.segments:
        lines += ["", "[[segment]]", f"hours = {h:.10g}   # {h * 60:.0f} min", f"rpm = {r:g}"]
    return "\n".join(lines) + "\n"


def predicted_csv(d: Design) -> str:
    header = ["t_h", "rpm", "milling", "t_peak_c", "s_mean_um", "s_std_um", "r_mean", "r_std", "temperature_c",
              "hardening"] + [f"target_{k}" for k in d.target]
    from .config import target_centre
    rows = []
    t = d.times_h
    for k in range(d.X.shape[0]):
        u = d.U[k] if k < d.U.shape[0] else (float("nan"), float("nan"))
        tp = d.t_peak_c[k] if k < d.U.shape[0] else float("nan")
        rows.append([float(t[k]), float(u[0]), float(u[1]), float(tp), *map(float, d.X[k])] +
                    [target_centre(v) for v in d.target.values()])
    return csv_text(header, rows)


def design_figure(d: Design, path: Path) -> None:
    """Schedule (rpm per segment, rests shaded), size moments and D50 (µm), r, vial temperature."""
    from ..io import pyplot, savefig
    from .config import target_bounds
    from .outputs import output_values

    from ..plots import quantity_label

    plt = pyplot()
    t = d.times_h
    fig, axes = plt.subplots(2, 2, figsize=(11, 6.5), sharex=True)
    ax = axes[0, 0]
    ax.step(t, np.append(d.U[:, 0], d.U[-1:, 0]), where="post", color="tab:blue", label="rpm (0 = rest)")
    ax.set_ylabel("rpm")
    ax.set_title(f"schedule: {d.result.switches} on/off switches")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    X = d.X
    d50 = np.asarray(output_values(X, ["d50_um"])[0], dtype=float)
    for ax, series, lab in ((axes[0, 1], (("s_mean_um", X[:, 0]), ("s_std_um", X[:, 1]), ("d50_um", d50)),
                             "size (µm); d50: volume-weighted"),
                            (axes[1, 0], (("r_mean", X[:, 2]), ("r_std", X[:, 3])), "irregularity r = 1 − πs/L")):
        for key, y in series:
            line, = ax.plot(t, y, label=key)
            if key in d.target:
                lo, hi = target_bounds(d.target[key])
                if hi > lo:
                    ax.axhspan(lo, hi, color=line.get_color(), alpha=0.15, label=f"target window {key}")
                else:
                    ax.axhline(lo, color=line.get_color(), ls="--", lw=1, label=f"target {key}")
        ax.set_ylabel(lab)
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    ax = axes[1, 1]
    ax.plot(t, X[:, 4], color="tab:red", label="vial temperature at segment ends")
    ax.axhline(d.ceiling_c, color="k", ls="--", lw=1, label="ceiling")
    ax.set_ylabel("vial temperature (°C)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("batch time t (h)")
    fig.suptitle(f"{d.card_name}: designed schedule (moment-model prediction)")
    # fixed margins: tight_layout and a tight bounding box would each draw the figure once more to measure it
    fig.subplots_adjust(left=0.07, right=0.985, bottom=0.08, top=0.9, wspace=0.2, hspace=0.16)
    savefig(fig, path, dpi=110)


def write_design(d: Design, out: Path) -> list[Path]:
    """Write schedule.toml, predicted.csv and design.png under ``out`` (atomically)."""
    out = Path(out)
    paths = [out / "schedule.toml", out / "predicted.csv", out / "design.png"]
    write_text(paths[0], schedule_toml(d))
    write_text(paths[1], predicted_csv(d))
    design_figure(d, paths[2])
    return paths
