"""Numerics of the moment equations: the numpy/casadi backends, smooth min/max helpers and the
quadrature nodes (Gauss-Hermite over ln s, Gauss-Legendre over the fracture split).

:mod:`bmctl.moments.equations` builds every equation from these.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

# --- backends -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Backend:
    name: str
    exp: Callable
    log: Callable
    sqrt: Callable
    stack: Callable
    fmin: Callable


def _np_stack(xs):
    return np.stack(np.broadcast_arrays(*[np.asarray(v, dtype=float) for v in xs]), axis=-1)


NP = Backend("numpy", np.exp, np.log, np.sqrt, _np_stack, np.minimum)


def _ca_backend() -> Backend:
    import casadi as ca

    return Backend("casadi", ca.exp, ca.log, ca.sqrt, lambda xs: ca.vertcat(*xs), ca.fmin)


def backend(xp: Any) -> Backend:
    """Backend for ``xp``: the numpy or casadi module (or a Backend, or the strings)."""
    if isinstance(xp, Backend):
        return xp
    name = xp if isinstance(xp, str) else getattr(xp, "__name__", "")
    if name == "numpy":
        return NP
    if name == "casadi":
        return CA()
    raise ValueError(f"xp: expected numpy or casadi (got {xp!r})")


_CA_CACHE: list[Backend] = []


def CA() -> Backend:  # noqa: N802 - a constant-like accessor
    if not _CA_CACHE:
        _CA_CACHE.append(_ca_backend())
    return _CA_CACHE[0]


# --- smooth helpers ---------------------------------------------------------------------------


def smax(B, a, lo, eps):
    """Smooth max(a, lo): lo + ((a - lo) + sqrt((a - lo)^2 + eps^2)) / 2  (>= lo, ~a for a >> lo + eps)."""
    d = a - lo
    return lo + 0.5 * (d + B.sqrt(d * d + eps * eps))


def smin(B, a, hi, eps):
    """Smooth min(a, hi)."""
    d = hi - a
    return hi - 0.5 * (d + B.sqrt(d * d + eps * eps))


def sat(B, q):
    """Smooth min(q, 1) for q >= 0: q / (1 + q^4)^(1/4) (a probability that saturates)."""
    q2 = q * q
    return q / B.sqrt(B.sqrt(1.0 + q2 * q2))


def node_exps(B, k):
    """exp(k t) at the Gauss-Hermite nodes t (symmetric about 0, with t = 0 in the middle)."""
    half = [B.exp(k * GH_T[j]) for j in range(N_S // 2 + 1, N_S)]
    return [1.0 / v for v in reversed(half)] + [1.0] + half


def node_sigmoids(B, a, ev):
    """sigmoid(a + v_k) = 1 / (1 + e^-a ev_k) from ev_k = exp(-v_k); -a is capped at 600 (|v_k| stays
    < 100), so nothing overflows. The field writes every logistic law this way, capped on the side
    that can overflow: exp is 3x cheaper than tanh in casadi's virtual machine and, unlike
    0.5 (1 + tanh(v / 2)), keeps the relative precision of small probabilities."""
    ea = B.exp(B.fmin(-a, 600.0))
    return [1.0 / (1.0 + ea * e) for e in ev]


# --- quadrature ---------------------------------------------------------------------------------

N_S = 5  # Gauss-Hermite nodes over ln s
N_X = 4  # Gauss-Legendre nodes over the fracture split x in (0, 1)
_T, _W = np.polynomial.hermite_e.hermegauss(N_S)
GH_T = tuple(float(v) for v in _T)
assert N_S % 2 == 1 and GH_T[N_S // 2] == 0.0 and all(abs(GH_T[k] + GH_T[-1 - k]) < 1e-14 for k in range(N_S // 2))
GH_W = tuple(float(v) for v in _W / math.sqrt(2 * math.pi))
_XL, _WL = np.polynomial.legendre.leggauss(N_X)
GL_X = tuple(float(0.5 * (v + 1)) for v in _XL)
GL_W = tuple(float(0.5 * v) for v in _WL)
# Every quantity of a split at x (eqn 20's x (1 - x), the fragment pair) is symmetric in x <-> 1 - x
# and so are the nodes: the fracture sums run over the lower half with doubled weights.
GL_XH = GL_X[: N_X // 2]
GL_WH = tuple(2.0 * v for v in GL_W[: N_X // 2])
assert N_X % 2 == 0 and all(abs(GL_X[k] + GL_X[-1 - k] - 1) < 1e-14 and abs(GL_W[k] - GL_W[-1 - k]) < 1e-14
                            for k in range(N_X // 2))
