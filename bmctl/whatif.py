"""What-if rpm schedules: each schedule on an ensemble of the plant, compared side by side
(the open loop of :func:`bmctl.loop.run_open_loop`, no feedback)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from . import io
from .config import ModelCard
from .loop import run_open_loop
from .physics.kinematics import kinematics
from .plant.plant import Plant
from .schedule import as_schedule

KEYS = ("s_mean_um", "s_std_um", "r_mean", "r_std", "temperature_c")


@dataclass
class WhatIfResult:
    """Ensemble of one schedule: times, per-seed trajectories, final particles, energy."""

    name: str
    t_h: np.ndarray
    traj: dict[str, np.ndarray]  # key -> (seeds, times)
    final_s_um: np.ndarray
    final_r: np.ndarray
    energy_kj: float
    hours: float
    peak_temperature_c: np.ndarray  # per seed

    def band(self, key: str):
        """Mean and 5-95 % band over seeds."""
        a = self.traj[key]
        return a.mean(axis=0), np.percentile(a, 5, axis=0), np.percentile(a, 95, axis=0)


@dataclass(frozen=True)
class _MemberTask:
    """Plain data of one ensemble member (pickled to Dask workers)."""

    card: ModelCard
    segments: tuple[tuple[float, float], ...]
    particles: int
    every_h: float


def _member(task: _MemberTask, rng: np.random.Generator) -> tuple:
    """One plant of the ensemble: ``task.segments`` open loop on a plant drawn from ``rng``.

    Returns
    -------
    tuple
        (recording times (h), {key: trajectory}, final s (µm), final r, peak temperature (°C)).
    """
    plant = Plant(task.card, rng, task.particles)
    recs: list[dict] = []
    t_h = run_open_loop(plant, list(task.segments), task.every_h, lambda t, mill: recs.append(mill.moments()))
    traj = {key: [m[key] for m in recs] for key in KEYS}
    return t_h, traj, plant.s * 1e6, plant.r, max(m["temperature_c"] for m in recs)


def run_schedule_ensemble(card: ModelCard, name: str, segments: Sequence[tuple[float, float]], seeds: int,
                          particles: int, base_seed: int = 0, every_h: float = 0.25, client=None) -> WhatIfResult:
    """Run ``segments`` on ``seeds`` plants (seeds base_seed .. base_seed + seeds - 1).

    Parameters
    ----------
    card : ModelCard or path-like
        The plant's model card (or its file).
    name : str
        Label of the schedule.
    segments : Schedule or sequence of (hours, rpm)
        The schedule; rpm 0 is a rest.
    seeds : int
        Ensemble size.
    particles : int
        Simulated particles per plant.
    base_seed : int, optional
        Seed: plant k draws from child k of ``SeedSequence(base_seed)`` (its ``spawn``).
    every_h : float, optional
        Recording interval (h).
    client : distributed.Client, optional
        Dask engine from :func:`bmctl.parallel.client_for`; None runs the plants serially in this
        process. The result is the same either way.

    Returns
    -------
    WhatIfResult

    Examples
    --------
    >>> from bmctl.config import load_card
    >>> from bmctl.whatif import run_schedule_ensemble
    >>> card = load_card("models/alni-1to1-300rpm-lab.toml")
    >>> res = run_schedule_ensemble(card, "1 h at 300 rpm", [(1.0, 300.0)], seeds=2, particles=500)
    >>> res.traj["s_mean_um"].shape          # (seeds, recorded times every 0.25 h)
    (2, 5)
    >>> bool((res.traj["s_mean_um"][:, -1] > 40.0).all())   # bonding outpaces fracture early
    True
    """
    from .parallel import map_seeded

    from .config import load_card
    from .errors import require_whole

    if isinstance(card, (str, os.PathLike)):
        card = load_card(card)
    elif not isinstance(card, ModelCard):
        raise TypeError(f"card: must be a ModelCard or a card file's path (got {type(card).__name__})")
    seeds, particles = require_whole(seeds, "seeds", 1), require_whole(particles, "particles", 2)
    base_seed = require_whole(base_seed, "base_seed", 0)
    segments = as_schedule(segments).pairs()
    hours = sum(h for h, _ in segments)
    task = _MemberTask(card, tuple((float(h), float(rpm)) for h, rpm in segments), particles, float(every_h))
    # plant k: child k of SeedSequence(base_seed), whatever the workers; neighbouring seeds share no plant
    members = map_seeded(_member, [task] * seeds, np.random.SeedSequence(base_seed).spawn(seeds), client)
    t_h = members[-1][0] if members else None
    traj = {k: np.array([m[1][k] for m in members]) for k in KEYS}
    energy = sum(kinematics(card, rpm).mean_power_W * h * 3600 for h, rpm in segments) / 1e3
    return WhatIfResult(name, t_h, traj, np.concatenate([m[2] for m in members]),
                        np.concatenate([m[3] for m in members]), energy, hours,
                        np.array([m[4] for m in members]))


#: the brackets a shared name's folder or file is put in: the first pair that no other schedule's own
#: name already shows after that name (``x (a)`` given as a name: the folders of two schedules named
#: ``x`` are ``x [a]``, ``x [b]``)
TAG_BRACKETS = (("(", ")"), ("[", "]"), ("{", "}"), ("<", ">"))


def unique_labels(names: Sequence[str], paths: Sequence[str | Path] | None = None) -> list[str]:
    """Labels of the schedules, one per schedule and all different.

    A name held by one schedule is its label. A name shared by several gets, for each of them, its
    file's folder (``name (folder)``), else the file as given (``name (file)``), else its place among
    them (``name #k``, counted from 1). No label made so is another schedule's own name, nor reads
    like a label made from one: where another schedule is named ``name (...)`` the folder or file is
    put in the first other brackets of :data:`TAG_BRACKETS` (``name [folder]``), and where one is
    named ``name #...`` the place is put in brackets (``name (#k)``).

    Parameters
    ----------
    names : sequence of str
        Each schedule's own name (its ``name``, else its file's stem).
    paths : sequence of str or Path, optional
        The schedule files as given (None: no file, the place in the list tells them apart).

    Returns
    -------
    list of str
        One label per schedule, in order.

    Examples
    --------
    >>> unique_labels(["design", "design", "ramp"], ["A/schedule.toml", "B/schedule.toml", "ramp.toml"])
    ['design (A)', 'design (B)', 'ramp']
    >>> unique_labels(["x", "x"], ["a/s.toml", "a/s.toml"])
    ['x #1', 'x #2']
    >>> unique_labels(["x", "x"])
    ['x #1', 'x #2']

    A schedule named like a label kept its name, and the others do not read like it:

    >>> unique_labels(["x", "x", "x #1"])
    ['x (#1)', 'x (#2)', 'x #1']
    >>> unique_labels(["x", "x", "x (a)"], ["a/s.toml", "b/s.toml", "c.toml"])
    ['x [a]', 'x [b]', 'x (a)']
    """
    import re
    from collections import Counter

    names = [str(n) for n in names]
    paths = [None] * len(names) if paths is None else [None if p is None else Path(p) for p in paths]

    def folder(p):
        return None if p is None else (p.parent.name or p.resolve().parent.name or str(p.parent))

    def as_given(p):
        return None if p is None else str(p)

    count = Counter(names)
    labels: list[str | None] = [n if count[n] == 1 else None for n in names]
    taken = set(names)  # every schedule's own name: no label made here may be one
    for base in dict.fromkeys(n for n in names if count[n] > 1):
        others = [n for n in count if n != base]
        b = re.escape(base)

        def imitated(pattern: str) -> bool:
            return any(re.fullmatch(pattern, o, re.DOTALL) for o in others)

        pending = [i for i, n in enumerate(names) if n == base]
        brackets = next(((o, c) for o, c in TAG_BRACKETS if not imitated(f"{b} {re.escape(o)}.*{re.escape(c)}")),
                        None)
        if brackets is not None:
            for tag in (folder, as_given):
                cand = {i: f"{base} {brackets[0]}{t}{brackets[1]}" for i in pending if (t := tag(paths[i]))}
                once = Counter(cand.values())
                for i, lab in cand.items():  # keep what tells a schedule apart, try the next tag on the rest
                    if once[lab] == 1 and lab not in taken:
                        labels[i] = lab
                        taken.add(lab)
                pending = [i for i in pending if labels[i] is None]
        if brackets is not None and imitated(f"{b} #.*"):
            def numbered(k, o=brackets[0], c=brackets[1]):
                return f"{base} {o}#{k}{c}"
        else:
            def numbered(k):
                return f"{base} #{k}"
        k = 0
        for i in pending:
            k += 1
            while numbered(k) in taken:  # only where every bracket is taken: never one of the names
                k += 1
            labels[i] = numbered(k)
            taken.add(labels[i])
    return labels


def table_rows(results: Sequence[WhatIfResult]) -> tuple[list[str], list[list]]:
    header = ["schedule", "hours", "energy_kj", "peak_temperature_c", "peak_temperature_c_q95"]
    for k in KEYS[:4]:
        header += [f"final_{k}", f"final_{k}_q05", f"final_{k}_q95"]
    rows = []
    for res, label in zip(results, unique_labels([r.name for r in results])):
        row = [label, res.hours, res.energy_kj, float(res.peak_temperature_c.mean()),
               float(np.percentile(res.peak_temperature_c, 95))]
        for k in KEYS[:4]:
            m, lo, hi = res.band(k)
            row += [float(m[-1]), float(lo[-1]), float(hi[-1])]
        rows.append(row)
    return header, rows


def write_outputs(results: Sequence[WhatIfResult], out: Path) -> list[Path]:
    """whatif.csv (table), whatif_moments.png (bands over time), whatif_final.png (final pdfs), as one
    set (:func:`bmctl.io.output_set`: all three or none, also on Ctrl-C)."""
    out = Path(out)
    paths = [out / "whatif.csv", out / "whatif_moments.png", out / "whatif_final.png"]
    with io.output_set():
        header, rows = table_rows(results)
        io.write_csv(paths[0], header, rows)
        _moments_figure(results, paths[1])
        _final_figure(results, paths[2])
    return paths


def _moments_figure(results: Sequence[WhatIfResult], path: Path) -> None:
    """Bands over batch time: five quantities and the peak vial temperature, 2 x 3 panels."""
    from . import plots

    plt = io.pyplot()
    fig, axes = plt.subplots(2, 3, figsize=(13.5, 7.6))
    labels = unique_labels([r.name for r in results])
    for i, res in enumerate(results):
        for ax, key in zip(axes.flat, KEYS):
            m, lo, hi = res.band(key)
            ax.plot(res.t_h, m, color=f"C{i}", label=labels[i])
            ax.fill_between(res.t_h, lo, hi, color=f"C{i}", alpha=0.2)
    for ax, key in zip(axes.flat, KEYS):
        ax.set_title(plots.quantity_label(key), fontsize=10), ax.set_xlabel("batch time (h)"), ax.grid(alpha=0.3)
    axes.flat[4].set_title("vial temperature at the recording times (°C)", fontsize=10)
    ax = axes.flat[5]
    x = np.arange(len(results))
    peak = np.array([r.peak_temperature_c.mean() for r in results])
    p95 = np.array([np.percentile(r.peak_temperature_c, 95) for r in results])
    for i in range(len(results)):
        ax.plot(x[i], peak[i], "o", color=f"C{i}", ms=9, label="mean over seeds" if i == 0 else None)
        ax.plot(x[i], p95[i], "v", color="k", ms=7, label="95th percentile" if i == 0 else None)
    ax.set_xticks(x, labels, rotation=20, ha="right", fontsize=8)
    ax.set_xlim(-0.6, len(results) - 0.4)
    ax.set_title("highest vial temperature of the batch (°C)", fontsize=10), ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize=8)
    axes.flat[0].legend(fontsize=8)
    seeds = min(len(r.peak_temperature_c) for r in results)
    fig.suptitle("what-if schedules: one plant per schedule (one seed: no band)" if seeds == 1
                 else f"what-if schedules: ensemble mean and 90 % band ({seeds} seeds)")
    fig.tight_layout()
    io.savefig(fig, path, dpi=110)


def _final_figure(results: Sequence[WhatIfResult], path: Path) -> None:
    """The particles at the end: size on a log axis (density per ln s), r up to where the data are."""
    from . import plots

    plt = io.pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
    s_all = np.concatenate([r.final_s_um for r in results])
    s_all = s_all[s_all > 0]
    edges = np.geomspace(max(np.percentile(s_all, 0.1), 1e-3) * 0.8, np.percentile(s_all, 99.9) * 1.25, 41)
    r_hi = max(float(np.percentile(np.concatenate([r.final_r for r in results]), 99.5)) * 1.15, 0.02)
    r_edges = np.linspace(0, min(r_hi, 1.0), 41)
    labels = unique_labels([r.name for r in results])
    for i, res in enumerate(results):
        s = res.final_s_um[res.final_s_um > 0]
        h, _ = np.histogram(s, bins=edges)
        axes[0].stairs(h / (s.size * np.diff(np.log(edges))), edges, color=f"C{i}", lw=1.5, label=labels[i])
        axes[1].hist(res.final_r, bins=r_edges, density=True, histtype="step", color=f"C{i}", lw=1.5)
    axes[0].set_xscale("log"), plots.log_size_axis(axes[0])
    axes[0].set_xlabel("final size s (µm, log scale)"), axes[1].set_xlabel(f"final {plots.R_LABEL}")
    axes[0].set_ylabel("density per ln s (by number)"), axes[0].legend(fontsize=8)
    axes[1].set_ylabel("density per unit r (by number)"), axes[1].set_xlim(0, r_edges[-1])
    seeds = min(len(r.peak_temperature_c) for r in results)
    fig.suptitle("what-if schedules: size and irregularity of the particles at the end "
                 + ("(one plant per schedule)" if seeds == 1 else f"(all {seeds} seeds pooled)"))
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    io.savefig(fig, path, dpi=110)
