"""Warped ellipses: a star-shaped particle outline with exactly known area and perimeter.

A shape is the polar curve (about its centre, in its own frame)

    rho(phi) = c * rho_ell(phi; q) * (1 + w cos(k phi + phase)),
    rho_ell(phi; q) = q / sqrt(cos(phi)^2 + q^2 sin(phi)^2)      (ellipse, half-axes q and 1)

rotated by ``theta``; ``c`` scales it to the section area ``pi s^2 / 4`` (size ``s``,
paper eqn 1). ``w = 0`` gives a plain ellipse of axis ratio ``q`` (``q = 1``: a disc);
``w > 0`` adds ``k`` lobes, the "warped ellipsoids" of the paper's Fig. 3 in 2D.

Area and perimeter come from a dense polygon of the analytic curve (4096 vertices:
relative error < 1e-5), so the aspect ratio ``r = 1 - pi s / L`` (eqn 3) of a shape is
known to far better than any image can measure it. ``r`` here always uses the true
boundary length ``L``; for a plain ellipse the paper's convention ``L = pi (a + b)``
(:func:`bmctl.plant.events.ellipse_size_aspect`) gives a slightly smaller ``r``
(q = 2: 0.057 instead of 0.083), see ``docs/measurement.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..plant.events import aspect_from_perimeter

N_EXACT = 4096  # polygon vertices for "exact" area/perimeter
N_SOLVE = 512  # vertices while solving for shape parameters (rel. error ~ 1e-4)
W_MAX = 0.3  # largest warp amplitude: rho stays >= 0.7 of the ellipse radius, no necks
Q_MAX = 50.0  # longest axis ratio the inverse solver tries


def unit_radius(phi, q, w, k, phase):
    """Radius of the unscaled shape (c = 1) at polar angle ``phi`` in the shape's own frame.

    Parameters
    ----------
    phi : array_like
        Polar angle(s), radians; broadcast against the shape parameters.
    q, w, k, phase : array_like
        Axis ratio (>= 1), warp amplitude (0 <= w < 1), lobe count, warp phase.

    Returns
    -------
    ndarray
        rho(phi) / c.
    """
    phi = np.asarray(phi, dtype=float)
    q = np.asarray(q, dtype=float)
    ell = q / np.sqrt(np.cos(phi) ** 2 + (q * np.sin(phi)) ** 2)
    return ell * (1.0 + np.asarray(w, dtype=float) * np.cos(np.asarray(k, dtype=float) * phi + phase))


def unit_area_perimeter(q, w, k, phase, n: int = N_EXACT) -> tuple[np.ndarray, np.ndarray]:
    """Area and perimeter of the unscaled shapes (c = 1), from an ``n``-gon of the curve.

    Parameters
    ----------
    q, w, k, phase : array_like, shape (m,)
        Shape parameters (see :func:`unit_radius`).
    n : int, optional
        Polygon vertices.

    Returns
    -------
    area, perimeter : ndarray, shape (m,)
    """
    q, w, k, phase = (np.atleast_1d(np.asarray(v, dtype=float)) for v in (q, w, k, phase))
    phi = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    rho = unit_radius(phi[None, :], q[:, None], w[:, None], k[:, None], phase[:, None])
    x, y = rho * np.cos(phi), rho * np.sin(phi)
    xn, yn = np.roll(x, -1, axis=1), np.roll(y, -1, axis=1)
    area = 0.5 * np.abs(np.sum(x * yn - xn * y, axis=1))
    perim = np.sum(np.hypot(xn - x, yn - y), axis=1)
    return area, perim


def unit_aspect(q, w, k, phase, n: int = N_EXACT) -> np.ndarray:
    """Aspect ratio r = 1 - pi s / L (eqn 3) of the shapes (scale-free)."""
    area, perim = unit_area_perimeter(q, w, k, phase, n)
    s = 2.0 * np.sqrt(area / np.pi)
    return aspect_from_perimeter(s, perim)


@dataclass(frozen=True)
class Shapes:
    """A set of warped ellipses, one per row; lengths in any unit (pixels for rendering).

    Attributes
    ----------
    s : ndarray
        Size (equivalent-disc diameter, eqn 1).
    q, w, k, phase, theta : ndarray
        Axis ratio (>= 1), warp amplitude, lobe count, warp phase, orientation (rad).
    """

    s: np.ndarray
    q: np.ndarray
    w: np.ndarray
    k: np.ndarray
    phase: np.ndarray
    theta: np.ndarray

    def __post_init__(self):
        m = np.atleast_1d(np.asarray(self.s, dtype=float))
        for name in ("s", "q", "w", "k", "phase", "theta"):
            v = np.broadcast_to(np.asarray(getattr(self, name), dtype=float), m.shape).copy()
            object.__setattr__(self, name, v)
        a0, l0 = unit_area_perimeter(self.q, self.w, self.k, self.phase)
        scale = np.sqrt(np.pi * self.s**2 / 4.0 / a0)
        object.__setattr__(self, "_scale", scale)
        object.__setattr__(self, "_perimeter", scale * l0)

    def __len__(self) -> int:
        return self.s.size

    @property
    def area(self) -> np.ndarray:
        """Section area pi s^2 / 4."""
        return np.pi * self.s**2 / 4.0

    @property
    def perimeter(self) -> np.ndarray:
        """True boundary length L."""
        return self._perimeter

    @property
    def r(self) -> np.ndarray:
        """Aspect ratio 1 - pi s / L with the true boundary length (eqn 3)."""
        return aspect_from_perimeter(self.s, self._perimeter)

    @property
    def rmax(self) -> np.ndarray:
        """Largest radius of each shape (bounding circle)."""
        phi = np.linspace(0.0, 2 * np.pi, 720, endpoint=False)
        return self._scale * np.max(
            unit_radius(phi[None, :], self.q[:, None], self.w[:, None], self.k[:, None], self.phase[:, None]), axis=1
        )

    def radius(self, i: int, phi) -> np.ndarray:
        """Radius of shape ``i`` along the image-frame direction ``phi`` (radians)."""
        return self._scale[i] * unit_radius(np.asarray(phi) - self.theta[i], self.q[i], self.w[i], self.k[i], self.phase[i])

    def scaled(self, factor: float) -> "Shapes":
        """The same shapes with all lengths multiplied by ``factor``."""
        return Shapes(self.s * factor, self.q, self.w, self.k, self.phase, self.theta)

    def coverage(self, i: int, cy: float, cx: float, ss: int = 4) -> tuple[tuple[slice, slice], np.ndarray]:
        """Anti-aliased coverage of shape ``i`` centred at (cy, cx) pixels.

        Pixel (y, x) covers [y - 1/2, y + 1/2] x [x - 1/2, x + 1/2]; coverage is the share of
        ``ss`` x ``ss`` sub-pixel samples inside the curve (``ss = 1``: pixel-centre test).

        Returns
        -------
        (rows, cols) : tuple of slices
            Window in the (unbounded) pixel grid; may extend below 0 (caller clips).
        cov : ndarray of float, in [0, 1]
        """
        R = float(self.rmax[i]) + 1.0
        y0, y1 = int(np.floor(cy - R)), int(np.ceil(cy + R)) + 1
        x0, x1 = int(np.floor(cx - R)), int(np.ceil(cx + R)) + 1
        off = (np.arange(ss) + 0.5) / ss - 0.5
        yy = (np.arange(y0, y1)[:, None] + off[None, :]).ravel() - cy
        xx = (np.arange(x0, x1)[:, None] + off[None, :]).ravel() - cx
        Y, X = np.meshgrid(yy, xx, indexing="ij")
        inside = np.hypot(Y, X) < self.radius(i, np.arctan2(Y, X))
        cov = inside.reshape(y1 - y0, ss, x1 - x0, ss).mean(axis=(1, 3))
        return (slice(y0, y1), slice(x0, x1)), cov


def _bisect(fun, lo, hi, target, iters: int = 40):
    """Vectorised bisection for increasing ``fun``: x in [lo, hi] with fun(x) = target."""
    lo, hi = np.array(lo, dtype=float), np.array(hi, dtype=float)
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        up = fun(mid) < target
        lo = np.where(up, mid, lo)
        hi = np.where(up, hi, mid)
    return 0.5 * (lo + hi)


def shapes_for(s, r, rng: np.random.Generator, *, elongation_share=None, k_range=(3, 5)) -> Shapes:
    """Warped ellipses with prescribed size ``s`` and true-perimeter aspect ratio ``r``.

    The excess perimeter is split at random between elongation (the axis ratio ``q``) and
    warp (``w`` with ``k`` lobes): ``q`` is solved so that a plain ellipse has aspect
    ``f r`` (f ~ U(0, 1) unless ``elongation_share`` is given), then ``w`` so that the
    warped ellipse has aspect ``r``. Where ``w`` would exceed ``W_MAX``, a plain ellipse
    (``w = 0``) carries all of ``r``. Orientation and phase are uniform.

    Parameters
    ----------
    s, r : array_like
        Sizes (any length unit) and aspect ratios in [0, 1).
    rng : numpy.random.Generator
        Source of the random split, lobe count, phase and orientation.
    elongation_share : float or array_like, optional
        Fixed share f of ``r`` carried by elongation.
    k_range : (int, int), optional
        Lobe counts drawn uniformly from this closed range.

    Returns
    -------
    Shapes

    Examples
    --------
    >>> import numpy as np
    >>> sh = shapes_for([20.0, 30.0], [0.0, 0.1], np.random.default_rng(0))
    >>> np.allclose(sh.r, [0.0, 0.1], atol=1e-3)
    True
    """
    s = np.atleast_1d(np.asarray(s, dtype=float))
    r = np.broadcast_to(np.asarray(r, dtype=float), s.shape).copy()
    m = s.size
    f = rng.random(m) if elongation_share is None else np.broadcast_to(np.asarray(elongation_share, float), s.shape)
    k = rng.integers(k_range[0], k_range[1] + 1, size=m).astype(float)
    phase = rng.uniform(0, 2 * np.pi, m)
    theta = rng.uniform(0, np.pi, m)
    zero = np.zeros(m)

    def r_of_q(qv):
        return unit_aspect(qv, zero, k, phase, N_SOLVE)

    q = _bisect(r_of_q, np.ones(m), np.full(m, Q_MAX), f * r)
    w_cap = unit_aspect(q, np.full(m, W_MAX), k, phase, N_SOLVE)
    warp_ok = w_cap >= r
    w = _bisect(lambda wv: unit_aspect(q, wv, k, phase, N_SOLVE), zero, np.full(m, W_MAX), r)
    q_all = _bisect(r_of_q, np.ones(m), np.full(m, Q_MAX), r)
    q = np.where(warp_ok, q, q_all)
    w = np.where(warp_ok, w, 0.0)
    w = np.where(r <= 0, 0.0, w)
    q = np.where(r <= 0, 1.0, q)
    return Shapes(s, q, w, k, phase, theta)
