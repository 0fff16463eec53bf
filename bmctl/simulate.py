"""Run the plant over a schedule and write moments.csv, population.npz and figures."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from . import io, plots
from .config import ModelCard
from .plant.plant import Plant, Record
from .plant.population import DR, DS_UM, MOMENT_NAMES, raster_edges

MOMENTS_HEADER = ("t_h", "s_mean_um", "s_std_um", "s_mode_um", "r_mean", "r_std", "r_mode",
                  "temperature_c", "bond_events", "fracture_events")


@dataclass
class SimulationResult:
    """Records of one run and the card it ran on."""

    card: ModelCard
    records: list[Record]

    def column(self, key: str) -> np.ndarray:
        """One column of the moments table as an array."""
        if key == "t_h":
            return np.array([r.t_h for r in self.records])
        if key == "temperature_c":
            return np.array([r.temperature_c for r in self.records])
        if key == "bond_events":
            return np.array([r.bonds for r in self.records])
        if key == "fracture_events":
            return np.array([r.fractures for r in self.records])
        return np.array([r.moments[key] for r in self.records])


def simulate(card: ModelCard, segments: Sequence[tuple[float, float]], seed: int | None = None,
             particles: int | None = None, record_every_h: float | None = None, progress=None) -> SimulationResult:
    """Run the plant from its initial powder over (hours, rpm) segments.

    Parameters
    ----------
    card : ModelCard
        The model card.
    segments : sequence of (hours, rpm)
        The schedule; rpm 0 is a rest.
    seed : int, optional
        Seed of the run's single random generator.
    particles : int, optional
        Simulated particles M (default: the card's).
    record_every_h : float, optional
        Recording interval (default: the card's, 1 h).
    progress : callable, optional
        Called with hours done per step.

    Returns
    -------
    SimulationResult

    Examples
    --------
    >>> from bmctl.plant import default_card
    >>> res = simulate(default_card(), [(1.0, 300.0)], seed=0, particles=500)
    >>> res.column("t_h").tolist()
    [0.0, 1.0]
    """
    plant = Plant(card, np.random.default_rng(seed), particles)
    every = record_every_h or card.simulation.record_every_h
    records = plant.run_schedule(segments, every, keep_raster=True, progress=progress)
    return SimulationResult(card, records)


def write_outputs(res: SimulationResult, out: Path) -> list[Path]:
    """Write moments.csv, population.npz and three PNG figures into ``out`` (each file atomically)."""
    out = Path(out)
    rows = []
    for r in res.records:
        rows.append([r.t_h, *(r.moments[k] for k in MOMENT_NAMES), r.temperature_c, r.bonds, r.fractures])
    paths = [out / "moments.csv", out / "population.npz", out / "size_pdf.png", out / "aspect_pdf.png",
             out / "moments.png"]
    io.write_csv(paths[0], MOMENTS_HEADER, rows)
    s_edges, r_edges = raster_edges(res.card.simulation.s_max_um)
    p = np.stack([r.p for r in res.records]).astype(np.float32)
    t_h = res.column("t_h")
    io.savez(paths[1], p=p, t_h=t_h, s_edges_um=s_edges, r_edges=r_edges,
             s_centers_um=0.5 * (s_edges[1:] + s_edges[:-1]), r_centers=0.5 * (r_edges[1:] + r_edges[:-1]))
    ps = p.sum(axis=2)
    pr = p.sum(axis=1)
    smax = float(np.percentile(np.concatenate([res.column("s_mean_um") + 4 * res.column("s_std_um")]), 100))
    name = res.card.card.name
    plots.pdf_over_time(paths[2], 0.5 * (s_edges[1:] + s_edges[:-1]), ps, t_h, "size s (um), bins of 1 um",
                        f"{name}: size pdf over time", xmax=min(smax, res.card.simulation.s_max_um))
    plots.pdf_over_time(paths[3], 0.5 * (r_edges[1:] + r_edges[:-1]), pr, t_h, "aspect ratio r, bins of 0.01",
                        f"{name}: aspect-ratio pdf over time", xmax=1.0)
    cols = {k: res.column(k) for k in MOMENTS_HEADER}
    plots.moments_over_time(paths[4], t_h, cols, f"{name}: moments over time")
    return paths


__all__ = ["simulate", "write_outputs", "SimulationResult", "MOMENTS_HEADER", "DS_UM", "DR"]
