"""Bounded work: every command that can run long estimates its CPU time and memory first, and
refuses (one line naming the flags to change and the budget) what exceeds the budget.

The budget is the user's: ``--budget-cpu-h H`` and ``--budget-memory-gb G`` on each such
command, else the environment (``BMCTL_BUDGET_CPU_H``, ``BMCTL_BUDGET_MEMORY_GB``), else a
default an interactive user accepts: :data:`DEFAULT_CPU_H` CPU hours (minutes of waiting on a
few cores) and half of this machine's memory. A bigger run is one flag away.

The estimates are models of each command's dominant cost with constants measured on this
project's machine and rounded towards the slow side (docs/reliability.md lists them):

* a plant run (``simulate``, ``whatif``, ``compare``, ``trial``, ``identify``, ``calibrate``):
  :func:`bmctl.cards.simulation_work` (impacts and time steps);
* the particle filter (``estimate``, ``trial``): :func:`filter_work` (moment-model steps of
  every particle over the hours it covers);
* the moment model alone (``linearize``): :func:`moment_work`;
* a calibration: :func:`calibrate_work` (its plant runs: design points x replicates x histories)
  and :func:`identify_work` (the calibrated card's moment coefficients are identified with it).

Examples
--------
>>> w = filter_work(hours=1000.0, particles=1_000_000)
>>> round(w["cpu_s"] / 3600)
19
"""

from __future__ import annotations

import math
import os

from .errors import InputError

#: the default CPU budget (hours of CPU time): minutes of waiting, not a day
DEFAULT_CPU_H = 1.0
#: CPU seconds of one moment-model step of one filter particle per hour of milling, and per hour
#: for the whole ensemble (measured: 100 particles 0.073 s/h, 1,000: 0.134 s/h, 10,000: 0.57 s/h in the
#: predict step; a whole `bmctl estimate` of 659 h at 100 particles: 0.14 s/h)
FILTER_CPU_S_PER_PARTICLE_H = 7e-5
FILTER_CPU_S_PER_H = 0.15
#: bytes per filter particle (states, parameters, weights and the copies a step makes)
FILTER_PARTICLE_BYTES = 2000
#: CPU seconds of the moment model per simulated hour (one trajectory; 1000 h: ~1 s)
MOMENT_CPU_S_PER_H = 2e-3
#: one micrograph in ``bmctl measure``: peak bytes per pixel while it is segmented (measured: 215 B/px at
#: 4.5 and 18 Mpx, peak RSS; both polarity readings of a near-tie add more), bytes per pixel each measured
#: image keeps until the set is written (the image, labels, masks, smoothed copy), CPU seconds per pixel
#: (measured: 5e-6, one reading)
MEASURE_PEAK_BYTES_PER_PX = 300
MEASURE_KEPT_BYTES_PER_PX = 40
MEASURE_CPU_S_PER_PX = 1e-5

_override: dict[str, float] = {}


def set_budget(cpu_h: float | None = None, memory_gb: float | None = None) -> None:
    """Set the budget from a command's flags (None: leave the environment's or the default).

    Parameters
    ----------
    cpu_h : float, optional
        CPU hours.
    memory_gb : float, optional
        Memory, GiB.
    """
    _override.clear()
    if cpu_h is not None:
        _override["cpu_s"] = float(cpu_h) * 3600.0
    if memory_gb is not None:
        _override["memory_bytes"] = float(memory_gb) * 2**30


def budget() -> dict[str, float]:
    """The work budget: ``cpu_s`` and ``memory_bytes`` (flags, else environment, else default).

    ``--budget-cpu-h`` / ``BMCTL_BUDGET_CPU_H`` (default :data:`DEFAULT_CPU_H` h) and
    ``--budget-memory-gb`` / ``BMCTL_BUDGET_MEMORY_GB`` (default half of the physical memory).
    """
    def env(name: str, default: float) -> float:
        text = os.environ.get(name)
        if text is None:
            return default
        try:
            v = float(text)
        except ValueError:
            raise InputError(f"{name}: not a number: {text[:40]!r}") from None
        if not (math.isfinite(v) and v > 0):
            raise InputError(f"{name}: must be a positive number (got {text[:40]})")
        return v

    try:
        phys = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # pragma: no cover - non-POSIX
        phys = 8 * 2**30
    out = {"cpu_s": env("BMCTL_BUDGET_CPU_H", DEFAULT_CPU_H) * 3600.0,
           "memory_bytes": env("BMCTL_BUDGET_MEMORY_GB", phys / 2 / 2**30) * 2**30}
    out.update(_override)
    return out


def check_work(work: dict[str, float], flags: str) -> None:
    """Refuse a run whose estimate exceeds :func:`budget`, naming the flags and the limit.

    Parameters
    ----------
    work : dict
        Any dict with ``cpu_s`` and ``memory_bytes`` (and optionally ``impacts``, ``steps``,
        ``records`` for the message).
    flags : str
        What the user can change, e.g. ``"--hours/--particles"``.
    """
    b = budget()
    cpu, mem = work["cpu_s"], work["memory_bytes"]
    if not cpu <= b["cpu_s"]:
        detail = f" ({work['impacts']:.3g} impacts, {work.get('steps', 0):.3g} steps)" if "impacts" in work else ""
        raise InputError(f"{flags}: the run would take ~{_hours(cpu)} CPU hours{detail}, over the budget "
                         f"of {b['cpu_s'] / 3600:g} h (--budget-cpu-h or BMCTL_BUDGET_CPU_H allow more)")
    if not mem <= b["memory_bytes"]:
        detail = f" ({work['records']:.3g} recorded populations)" if "records" in work else ""
        raise InputError(f"{flags}: the run would need ~{mem / 2**30:.3g} GiB{detail}, over the budget of "
                         f"{b['memory_bytes'] / 2**30:.3g} GiB (--budget-memory-gb or BMCTL_BUDGET_MEMORY_GB "
                         "allow more)")


def _hours(cpu_s: float) -> str:
    return f"{cpu_s / 3600:.3g}" if math.isfinite(cpu_s) else "inf"


def add(*works: dict[str, float]) -> dict[str, float]:
    """Work of runs one after another: CPU and counts add, memory is the largest.

    Parameters
    ----------
    *works : dict
        Estimates.
    """
    out: dict[str, float] = {"cpu_s": 0.0, "memory_bytes": 0.0}
    for w in works:
        for k, v in w.items():
            out[k] = max(out.get(k, 0.0), v) if k == "memory_bytes" else out.get(k, 0.0) + v
    return out


def scale(work: dict[str, float], times: float) -> dict[str, float]:
    """Work of ``times`` runs of ``work`` (one after another; memory of one).

    Parameters
    ----------
    work : dict
        One run's estimate.
    times : float
        How many.
    """
    return {k: (v if k == "memory_bytes" else v * times) for k, v in work.items()}


def filter_work(hours: float, particles: int) -> dict[str, float]:
    """Estimated work of a particle filter carried over ``hours`` of milling with ``particles``.

    Parameters
    ----------
    hours : float
        Time the filter propagates (the last sample time, or the trial's length).
    particles : int
        Filter particles N.
    """
    hours = max(0.0, float(hours))
    return {"cpu_s": hours * (FILTER_CPU_S_PER_H + FILTER_CPU_S_PER_PARTICLE_H * particles),
            "memory_bytes": particles * FILTER_PARTICLE_BYTES}


def measure_work(pixels) -> dict[str, float]:
    """Estimated work of ``bmctl measure`` on images of ``pixels`` each (measured one after another;
    each keeps its image and labels until the output set is written).

    Parameters
    ----------
    pixels : sequence of int
        Pixels of each image (the header's count).

    Examples
    --------
    >>> round(measure_work([8000 * 8000])["memory_bytes"] / 2**30, 1)
    20.3
    """
    px = [max(0, int(p)) for p in pixels]
    if not px:
        return {"cpu_s": 0.0, "memory_bytes": 0.0}
    return {"cpu_s": MEASURE_CPU_S_PER_PX * sum(px),
            "memory_bytes": float(MEASURE_PEAK_BYTES_PER_PX * max(px) + MEASURE_KEPT_BYTES_PER_PX * sum(px))}


def moment_work(hours: float) -> dict[str, float]:
    """Estimated work of one moment-model trajectory over ``hours``.

    Parameters
    ----------
    hours : float
        Simulated time.
    """
    return {"cpu_s": max(0.0, float(hours)) * MOMENT_CPU_S_PER_H, "memory_bytes": 1e6 + 1e3 * max(0.0, hours)}


def calibrate_work(card, histories, n_params: int, particles: int, replicates: int, max_iter: int = 8,
                   ridge_points: int = 17) -> dict[str, float]:
    """Estimated work of ``bmctl calibrate``: plant runs of every history to its last sample, at
    every design point of at most ``max_iter`` central-difference iterations (2 p + 1 points),
    the start comparison, the ridge scan and the final draw, ``replicates`` times each.

    Parameters
    ----------
    card : ModelCard
    histories : sequence of History
        (hours, rpm, milling) segments and sample times.
    n_params : int
        Parameters fitted (p).
    particles : int
        Plant particles per run.
    replicates : int
        Common-random-number runs per design point.
    max_iter : int, optional
        The fit's iteration limit.
    ridge_points : int, optional
        Points of the ridge scan.
    """
    from .cards import simulation_work

    points = 2 + max_iter * (2 * n_params + 1) + ridge_points + 1
    one = {"cpu_s": 0.0, "memory_bytes": 0.0}
    for h in histories:
        end = h.times_h[-1] if h.times_h else 0.0
        segs, t = [], 0.0
        for hours, rpm, milling in h.segments:
            if t >= end:
                break
            take = min(hours, end - t)
            segs += [(take * milling, rpm), (take * (1.0 - milling), 0.0)]
            t += take
        segs = [s for s in segs if s[0] > 0] or [(1e-3, 0.0)]
        one = add(one, simulation_work(card, segs, particles, max(end, 1e-3), raster=False))
    return scale(one, points * replicates)


def identify_work(card, seed: int = 0, quick: bool = False, particles: int | None = None,
                  random_schedules: int | None = None) -> dict[str, float]:
    """Estimated plant work of identifying ``card``'s moment coefficients as ``bmctl identify``
    does (training, held-out and off-card experiments on their seeds).

    Parameters
    ----------
    card : ModelCard
    seed : int, optional
        Seed of the design.
    quick : bool, optional
        The ``--quick`` design.
    particles : int, optional
        Plant particles (default: identify's).
    random_schedules : int, optional
        Random schedules in the design (default: identify's).
    """
    from .cards import identify_work as plant_identify_work
    from .moments import identify as ident

    n_train, n_valid = (1, 2) if quick else (len(ident.TRAIN_SEEDS), len(ident.VALID_SEEDS))
    specs = ident.design(card, seed, quick, random_schedules)
    vspecs = ident.validation_design(card, seed, 4 if quick else ident.N_VALID)
    return plant_identify_work(card, [(specs, n_train), (vspecs, n_valid), (ident.off_card_design(card), n_valid)],
                               particles or (2000 if quick else 4000), ident.DT_H)
