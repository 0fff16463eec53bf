"""What a micrograph would measure from a particle population: the plant's sampling model.

:func:`micrograph_sample` draws ``n`` measured particles from a population of sizes and
aspect ratios (e.g. a plant snapshot). Two paths:

fast (default)
    1. draw particles uniformly (with replacement) from the population, or in proportion
       to s when ``section=True`` (a plane cuts a particle with probability proportional
       to its size);
    2. optional random planar section (``section=True``): a plane at a uniformly random
       distance from the centre of a sphere-like particle of diameter s shows a section
       of size ``s sqrt(1 - u^2)``, u ~ U(0, 1) (mean factor pi/4); r is kept, as no 3-D
       shape is known. Use it only when the population's s is a 3-D diameter: the paper's
       s is itself a 2-D section size, for which ``section=False`` (default) is right;
    3. resolution (``um_per_px`` given): particles whose area is below ``min_area_px``
       pixels are lost (not detected); pixel quantisation adds relative noise
       ``QUANT_AREA / d^1.5`` to the area and ``QUANT_PERIMETER / d`` to the perimeter
       (d = s in px; both fitted to the perimeter-bias study, docs/measurement.md);
    4. segmentation noise: independent log-normal factors of sigma ``noise`` on area and
       perimeter (default 0.03, from the real-image validation); perimeters pushed below
       the isoperimetric bound pi s are set to it (r = 0), as the measurement does.

render (``render=True``)
    the particles are drawn as warped ellipses of the same s and (true-perimeter) r into
    synthetic micrographs (:mod:`bmctl.measure.render`: blur, noise, uneven background,
    touching pairs) and measured by the real segmentation path; particles that do not fit
    in the field of view are lost. Slow (about 2 s per 100 particles).

All randomness comes from the ``rng`` passed in.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from .render import render_micrograph
from .segment import MIN_AREA_PX, measure_labels, segment
from .shapes import shapes_for
from .tables import ParticleTable

QUANT_AREA = 0.5  # relative area std of a pixel count: 0.5 d^-1.5 (1.6 % at d = 10 px)
QUANT_PERIMETER = 0.12  # relative std of the Crofton perimeter: 0.12 / d (1.2 % at d = 10 px)
NOISE = 0.03  # segmentation noise (log-normal sigma) on area and perimeter
RENDER_MEDIAN_PX = 30.0  # render path without um_per_px: median particle 30 px across
MAX_DRAWS_FACTOR = 200  # give up when fewer than n of n * this many draws are detected


def _check_population(s_um, r) -> tuple[np.ndarray, np.ndarray]:
    s = np.asarray(s_um, dtype=float).ravel()
    r = np.asarray(r, dtype=float).ravel()
    if s.size == 0:
        raise InputError("population: no particles")
    if r.size != s.size:
        raise InputError(f"population: s has {s.size} values, r has {r.size}")
    if not (np.all(np.isfinite(s)) and np.all(np.isfinite(r))):
        raise InputError("population: s and r must be finite")
    if np.any(s <= 0):
        raise InputError(f"population: s must be > 0 (min {s.min():g})")
    if np.any((r < 0) | (r >= 1)):
        raise InputError(f"population: r must be in [0, 1) (range {r.min():g} to {r.max():g})")
    return s, r


def _draw(s, r, m, rng, section):
    if section:
        idx = rng.choice(s.size, size=m, p=s / s.sum())
        u = rng.random(m)
        return s[idx] * np.sqrt(1.0 - u**2), r[idx]
    idx = rng.integers(0, s.size, size=m)
    return s[idx], r[idx]


def resolvable_share(s_um, um_per_px: float, min_area_px: int = MIN_AREA_PX, section: bool = False) -> float:
    """Share of a sample's draws from a population that are large enough to measure at ``um_per_px``
    (an area of at least ``min_area_px``), as :func:`micrograph_sample` draws them.

    Parameters
    ----------
    s_um : array_like
        Particle sizes (µm).
    um_per_px : float
        Pixel size (µm).
    min_area_px : int, optional
        Detection limit (px of area).
    section : bool, optional
        Planar sections (drawn in proportion to s, at a uniform height through the sphere).

    Examples
    --------
    >>> resolvable_share([40.0, 40.0], 1.0), resolvable_share([40.0, 4.0], 1.0)
    (1.0, 0.5)
    """
    s = np.asarray(s_um, dtype=float)
    d_min = float(um_per_px) * np.sqrt(4.0 * min_area_px / np.pi)  # pi d^2 / 4 >= min_area_px px^2
    if not section:
        return float(np.mean(s >= d_min))
    # a section at height u (uniform) of a sphere of diameter s is s sqrt(1 - u^2) across: >= d_min for u below
    return float(np.sum(s / s.sum() * np.sqrt(np.clip(1.0 - (d_min / s) ** 2, 0.0, 1.0))))


def micrograph_sample(
    s_um,
    r,
    n: int,
    rng: np.random.Generator,
    *,
    um_per_px: float | None = None,
    noise: float = NOISE,
    section: bool = False,
    min_area_px: int = MIN_AREA_PX,
    render: bool = False,
) -> ParticleTable:
    """Draw ``n`` particles as a micrograph would measure them.

    Parameters
    ----------
    s_um, r : array_like
        The population: sizes in um (> 0) and aspect ratios in [0, 1).
    n : int
        Number of measured particles to return.
    rng : numpy.random.Generator
        The only source of randomness.
    um_per_px : float, optional
        Pixel size. ``None``: no resolution limit (fast path), or a median particle of
        ``RENDER_MEDIAN_PX`` px (render path).
    noise : float, optional
        Log-normal sigma of the segmentation noise on area and perimeter (fast path).
    section : bool, optional
        Apply the random planar-section factor (s is a 3-D diameter).
    min_area_px : int, optional
        Detection limit in px (both paths).
    render : bool, optional
        Go through the renderer and the real segmentation.

    Returns
    -------
    ParticleTable
        ``n`` rows.

    Raises
    ------
    bmctl.errors.InputError
        Bad population, n < 1, bad scale, or (almost) no particle resolvable.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> t = micrograph_sample(np.full(100, 50.0), np.full(100, 0.1), 20, rng, um_per_px=1.0)
    >>> len(t), bool(abs(np.median(t.s_um) - 50) < 2)
    (20, True)
    """
    s, r = _check_population(s_um, r)
    if int(n) != n or n < 1:
        raise InputError(f"n: must be an integer >= 1 (got {n})")
    n = int(n)
    if um_per_px is not None:
        um_per_px = float(um_per_px)
        if not np.isfinite(um_per_px) or um_per_px <= 0:
            raise InputError(f"um_per_px: must be a finite number > 0 (got {um_per_px})")
    if not np.isfinite(noise) or noise < 0:
        raise InputError(f"noise: must be >= 0 (got {noise})")
    if render:
        return _render_sample(s, r, n, rng, um_per_px, section, min_area_px)
    return _fast_sample(s, r, n, rng, um_per_px, noise, section, min_area_px)


def _fast_sample(s, r, n, rng, um_per_px, noise, section, min_area_px) -> ParticleTable:
    parts, got, drawn = [], 0, 0
    while got < n:
        if drawn >= MAX_DRAWS_FACTOR * n:
            raise InputError(
                f"population: only {got} of {drawn} particles are resolvable at {um_per_px} µm/px "
                f"(min area {min_area_px} px); need {n}"
            )
        m = max(2 * (n - got), 64)
        drawn += m
        ss, rr = _draw(s, r, m, rng, section)
        area = np.pi * ss**2 / 4.0
        perim = np.pi * ss / (1.0 - rr)
        if um_per_px is not None:
            d = ss / um_per_px
            keep = area / um_per_px**2 >= min_area_px
            d, area, perim = d[keep], area[keep], perim[keep]
            area = area * (1.0 + QUANT_AREA * d**-1.5 * rng.standard_normal(d.size))
            perim = perim * (1.0 + QUANT_PERIMETER / d * rng.standard_normal(d.size))
        area = area * np.exp(noise * rng.standard_normal(area.size))
        perim = perim * np.exp(noise * rng.standard_normal(perim.size))
        ok = (area > 0) & (perim > 0)
        parts.append(ParticleTable.from_area_perimeter(area[ok], perim[ok]))
        got += int(ok.sum())
    return ParticleTable.concat(parts).take(np.arange(n))


RENDER_SIDE_PX = (256, 2048)  # the rendered field's side: six times the 99th percentile particle, within these
#: the largest particle (its 99th percentile, px across) a rendered field of the largest side holds as drawn
RENDER_PARTICLE_MAX_PX = RENDER_SIDE_PX[1] / 6


def render_field(s_um, um_per_px: float | None) -> tuple[float, int, int]:
    """The rendered path's field for a population: (µm per px, side in px, particles per image).

    Parameters
    ----------
    s_um : array_like
        Particle sizes (µm).
    um_per_px : float or None
        Pixel size (None: the median particle ``RENDER_MEDIAN_PX`` px across).

    Examples
    --------
    >>> render_field([40.0] * 10, 1.0)
    (1.0, 256, 10)
    """
    s = np.asarray(s_um, dtype=float)
    if um_per_px is None:
        um_per_px = float(np.median(s)) / RENDER_MEDIAN_PX
    s_px = s / um_per_px
    side = int(np.clip(np.ceil(6 * np.quantile(s_px, 0.99)), *RENDER_SIDE_PX))
    mean_area = float(np.mean(np.pi * s_px**2 / 4.0)) * 1.3  # particles per image: ~25 % of the field covered
    return float(um_per_px), side, int(np.clip(0.25 * side * side / mean_area, 4, 400))


def _render_sample(s, r, n, rng, um_per_px, section, min_area_px) -> ParticleTable:
    um_per_px, side, m = render_field(s, um_per_px)
    parts, got, drawn = [], 0, 0
    while got < n:
        if drawn >= MAX_DRAWS_FACTOR * n:
            raise InputError(
                f"population: only {got} of {drawn} rendered particles were measured at {um_per_px:g} µm/px; need {n}"
            )
        ss, rr = _draw(s, r, m, rng, section)
        drawn += m
        shapes = shapes_for(ss / um_per_px, rr, rng)
        mic = render_micrograph(rng, shapes=shapes, shape=(side, side), um_per_px=um_per_px)
        seg = segment(mic.image, min_area_px=min_area_px)
        tab = measure_labels(seg.labels, um_per_px)
        parts.append(tab.take(rng.permutation(len(tab))))
        got += len(tab)
    return ParticleTable.concat(parts).take(np.arange(n))
