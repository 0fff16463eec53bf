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
from .stats import SIZE_STAT_NAMES

# number-weighted moments, then (appended) volume-weighted d10/d50/d90/span and area-weighted mean/mode
MOMENTS_HEADER = ("t_h", "s_mean_um", "s_std_um", "s_mode_um", "r_mean", "r_std", "r_mode",
                  "temperature_c", "bond_events", "fracture_events", *SIZE_STAT_NAMES)

#: population.npz: name -> (dimensions, unit, meaning and weighting); stored in the file as string arrays
POPULATION_VARIABLES = {
    "p": ("t, s, r", "1", "number fraction of particles per (s, r) raster bin (weight 1 per particle); sums to 1"),
    "p_volume": ("t, s, r", "1", "volume fraction per (s, r) raster bin (weight s^3, s at the bin centre); sums to 1"),
    "p_area": ("t, s, r", "1", "projected-area fraction per (s, r) raster bin (weight s^2, s at the bin centre)"),
    "t_h": ("t", "h", "recorded times"),
    "s_edges_um": ("s+1", "um", "size-bin edges (1 um raster)"),
    "s_centers_um": ("s", "um", "size-bin centres"),
    "r_edges": ("r+1", "1", "irregularity-bin edges, r = 1 - pi s / L (0 = round), raster 0.01"),
    "r_centers": ("r", "1", "irregularity-bin centres"),
}


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


def population_arrays(res: SimulationResult) -> dict[str, np.ndarray]:
    """The arrays of population.npz: rasters by number, area and volume, axes, and metadata.

    Metadata are plain string arrays (loadable with ``allow_pickle=False``): ``variables``,
    ``dims``, ``units`` and ``meaning`` list every data array, and ``weighting`` names the
    weight of each raster.
    """
    s_edges, r_edges = raster_edges(res.card.simulation.s_max_um)
    s_c = 0.5 * (s_edges[1:] + s_edges[:-1])
    p = np.stack([r.p for r in res.records])
    out = {"p": p.astype(np.float32)}
    for key, power in (("p_area", 2), ("p_volume", 3)):
        pw = p * (s_c**power)[None, :, None]
        out[key] = (pw / pw.sum(axis=(1, 2), keepdims=True)).astype(np.float32)
    out.update(t_h=res.column("t_h"), s_edges_um=s_edges, s_centers_um=s_c, r_edges=r_edges,
               r_centers=0.5 * (r_edges[1:] + r_edges[:-1]))
    names = list(POPULATION_VARIABLES)
    out.update(variables=np.array(names), dims=np.array([POPULATION_VARIABLES[k][0] for k in names]),
               units=np.array([POPULATION_VARIABLES[k][1] for k in names]),
               meaning=np.array([POPULATION_VARIABLES[k][2] for k in names]),
               weighting=np.array(["p: number (s^0)", "p_area: area (s^2)", "p_volume: volume (s^3)"]),
               card=np.array(res.card.card.name))
    return out


def write_outputs(res: SimulationResult, out: Path) -> list[Path]:
    """Write moments.csv, population.npz and four PNG figures into ``out`` (each file atomically).

    Figures: ``size_pdf.png`` (small multiples of the size distribution by number and by
    volume on a log size axis, cumulative volume, D50), ``size_heatmap.png`` (time-size maps,
    Fig. 9a analogue), ``aspect_pdf.png`` (irregularity r), ``moments.png`` (Fig. 12 analogue).
    """
    out = Path(out)
    rows = []
    for r in res.records:
        rows.append([r.t_h, *(r.moments[k] for k in MOMENT_NAMES), r.temperature_c, r.bonds, r.fractures,
                     *(r.moments[k] for k in SIZE_STAT_NAMES)])
    paths = [out / "moments.csv", out / "population.npz", out / "size_pdf.png", out / "aspect_pdf.png",
             out / "moments.png", out / "size_heatmap.png"]
    io.write_csv(paths[0], MOMENTS_HEADER, rows)
    arrays = population_arrays(res)
    io.savez(paths[1], **arrays)
    p = arrays["p"].astype(float)
    ps, pr = p.sum(axis=2), p.sum(axis=1)
    t_h = arrays["t_h"]
    s_edges = arrays["s_edges_um"]
    name = res.card.card.name
    cols = {k: res.column(k) for k in MOMENTS_HEADER}
    plots.size_distributions(paths[2], s_edges, ps, t_h, cols["d50_um"],
                             f"{name}: particle size distribution at selected batch times")
    plots.irregularity_distributions(paths[3], arrays["r_edges"], pr, t_h,
                                     f"{name}: particle irregularity r at selected batch times")
    plots.moments_over_time(paths[4], t_h, cols, f"{name}: size, shape and temperature over batch time")
    plots.size_heatmap(paths[5], s_edges, ps, t_h, cols,
                       f"{name}: size distribution over batch time (colour: density per ln s)")
    return paths


__all__ = ["simulate", "write_outputs", "population_arrays", "SimulationResult", "MOMENTS_HEADER",
           "POPULATION_VARIABLES", "DS_UM", "DR"]
