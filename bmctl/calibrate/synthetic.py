"""Synthetic histories: samples drawn from a plant whose parameters are known (benchmarks, tests)."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from ..config import ModelCard
from .history import History, MeasuredSample
from .simulate import run_history


def synthetic_history(card: ModelCard, segments: Sequence[tuple[float, float, float]], times_h: Sequence[float],
                      n: int, particles: int, rng: np.random.Generator, name: str = "synthetic") -> History:
    """Run the plant of ``card`` and draw ``n`` particles (without replacement) at each time.

    Parameters
    ----------
    card : ModelCard
        The true plant.
    segments : sequence of (hours, rpm, milling)
    times_h : sequence of float
    n : int
        Particles per sample.
    particles : int
        Simulated particles of the true plant (>= n).
    rng : numpy.random.Generator
    name : str, optional
        The history's name and path, and the prefix of each sample's source (``NAME@2h``).

    Returns
    -------
    History
    """
    pops = run_history(card, segments, times_h, particles, rng)
    samples = []
    for t, (s, r) in zip(times_h, pops):
        k = rng.choice(s.size, size=n, replace=False)
        samples.append(MeasuredSample(float(t), s[k], r[k], f"{name}@{t:g}h"))
    return History(name, name, [tuple(map(float, sg)) for sg in segments], samples)


def write_history(history: History, folder: str | Path) -> Path:
    """Write a history as TOML + one particle table per sample (``s_um,r``) into ``folder``."""
    from ..io import write_text
    from ..measure.tables import ParticleTable, write_table
    from ..io import toml_string

    folder = Path(folder)
    lines = [f"name = {toml_string(history.name)}", ""]
    for h, rpm, milling in history.segments:
        lines += ["[[segment]]", f"hours = {h!r}", f"rpm = {rpm!r}", f"milling = {milling!r}", ""]
    for k, smp in enumerate(history.samples):
        tab = f"{history.name}-t{k}.csv"
        write_table(folder / tab, ParticleTable.from_size_aspect(smp.s_um, smp.r))
        lines += ["[[sample]]", f"t_h = {smp.t_h!r}", f"table = {toml_string(tab)}", ""]
    path = folder / f"{history.name}.toml"
    write_text(path, "\n".join(lines))
    return path
