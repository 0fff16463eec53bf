"""Compiled (numba) event step of the plant: the numpy engine's batch of impacts as one fused loop.

:func:`impacts` does what :meth:`bmctl.plant.plant.Plant._impacts` does with the paper's
kernels (:class:`bmctl.plant.kernels.PaperKernels`): queue n new impacts, take the rounds of
first-in-queue impacts, draw and apply each round's physics, eqns (5)-(20), and rebalance.
It draws from the plant's own ``numpy.random.Generator`` in the numpy engine's order (each
kind of variate for the whole round, then the next kind): uniforms through the tables of
:mod:`bmctl.physics.samplers` (``p[P_TABULATED]``), or numpy's own Gamma/Beta samplers, which
numba runs on the same bit generator; every arithmetic step is written in the numpy code's
order of operations. A seed therefore gives the numpy engine's trajectory to the last bit
(tests/plant/test_plant_compiled.py), wherever numpy's float64 sin, cos and exp call the C
library, as they do on x86-64 without AVX-512; elsewhere the two agree to a relative 1e-12
(docs/performance.md).

Compiled code is cached on disk (numba ``cache=True``: next to this file, or in the user's
cache directory when the package folder is read-only). The background compile warms it with a
small card built in code (:func:`warmup_card`), so it needs nothing outside the package; a failed
compile leaves its error in ``$XDG_CACHE_HOME/bmctl`` (:func:`compile_failure`) and is not retried
for the same install.
"""

from __future__ import annotations

import math
import os

import numpy as np
from numba import njit

from ..physics.samplers import ENERGY_MAIN_U, ENERGY_TAIL_T, N_CELLS, N_TAIL_CELLS
from .events import R_MAX

# indices into the float parameter vector (built by Plant._numba_params)
P_THETA, P_TRAPPED, P_SQRT_A, P_SQRT_B, P_ZETA_B, P_XI_A = 0, 1, 2, 3, 4, 5
P_SIGMA, P_U_BOND, P_U_FRAC, P_ETA_EQ = 6, 7, 8, 9  # change with temperature and hardening (contiguous)
P_STRAIN_EFF, P_MAX_STRAIN = 10, 11
P_MODULUS, P_SHARPNESS, P_GAMMA, P_DELTA = 12, 13, 14, 15
P_TABULATED = 16  # 1: the tabulated samplers of bmctl.physics.samplers; 0: numpy's exact ones
N_PARAMS = 17

_E_SCALE = N_CELLS / ENERGY_MAIN_U  # as in bmctl.physics.samplers.tabulated_energies
_T0 = ENERGY_TAIL_T[0]
_T_SCALE = N_TAIL_CELLS / (ENERGY_TAIL_T[1] - ENERGY_TAIL_T[0])


@njit(cache=True, inline="always")  # inlined: a call would pay the tables' reference counts
def _tab_energy(u, main, tail):
    """U_in / theta from one uniform u: samplers.tabulated_energies, same operations.  (5)"""
    if u < ENERGY_MAIN_U:
        z = u * _E_SCALE
        k = min(int(z), N_CELLS - 1)
        if k == 0:
            return main[1] * np.cbrt(z)
        return main[k] + (z - k) * (main[k + 1] - main[k])
    zt = (-math.log1p(-u) - _T0) * _T_SCALE
    k = min(int(zt), N_TAIL_CELLS - 1)
    return tail[k] + (zt - k) * (tail[k + 1] - tail[k])


@njit(cache=True, inline="always")
def _tab_beta(u, q, a):
    """Beta(a, 2) from one uniform u: samplers.tabulated_beta_a2, same operations.  (9)"""
    z = u * N_CELLS
    k = int(z)
    if k == 0:
        return q[1] * z ** (1.0 / a)
    if k == N_CELLS - 1:
        return 1.0 - (1.0 - q[N_CELLS - 1]) * math.sqrt(N_CELLS - z)
    return q[k] + (z - k) * (q[k + 1] - q[k])


@njit(cache=True)
def _energies(rng, theta, n):
    """U_in of n impacts, weighted by (U_in - U_out) / U_in: events.sample_impact_energies.  (5)"""
    out = np.empty(n)
    have = 0
    while have < n:
        m = max(16, int(2.2 * (n - have)) + 8)
        g = np.empty(2 * m)
        for k in range(2 * m):
            g[k] = rng.gamma(1.5, theta)
        for k in range(m):
            hi = max(g[k], g[m + k])
            lo = min(g[k], g[m + k])
            if rng.random() * hi < hi - lo and have < n:
                out[have] = hi
                have += 1
    return out


@njit(cache=True)
def _threshold(du, u, sharpness):
    """p_u = 1 / (1 + exp(-k (du - u))) with k u = sharpness.  (17)"""
    x = min(max(sharpness * (du / u - 1.0), -60.0), 60.0)
    return 1.0 / (1.0 + math.exp(-x))


@njit(cache=True)
def _first_round(qi, qj, qv, seen):
    """Mask of queued impacts that come first in the queue for each of their slots i, j, v."""
    nq = qi.size
    ready = np.zeros(nq, dtype=np.bool_)
    for k in range(nq):
        a, b, c = qi[k], qj[k], qv[k]
        ready[k] = not (seen[a] or seen[b] or seen[c])
        seen[a] = True
        seen[b] = True
        seen[c] = True
    for k in range(nq):
        seen[qi[k]] = False
        seen[qj[k]] = False
        seen[qv[k]] = False
    return ready


@njit(cache=True)
def _round(rng, s, r, i, j, v, p, seen, tabs):
    """One round of impacts on pairs (i, j) sharing no slot: PaperKernels.impact + Plant._impact_round.

    Returns the numbers of bonds and fractures.
    """
    n = i.size
    pi = np.pi
    # draws, in the numpy engine's order
    tabulated = p[P_TABULATED] != 0.0
    if tabulated:
        u_in = np.empty(n)
        theta = p[P_THETA]
        for k in range(n):
            u_in[k] = _tab_energy(rng.random(), tabs[0], tabs[1]) * theta  # (5)
    else:
        u_in = _energies(rng, p[P_THETA], n)  # (5)
    phi = np.empty(n)
    for k in range(n):
        phi[k] = rng.uniform(-pi, pi)
    zeta = np.empty(2 * n)
    xi = np.empty(2 * n)
    if tabulated:
        for k in range(2 * n):
            zeta[k] = 1.0 - _tab_beta(rng.random(), tabs[2], p[P_ZETA_B])  # (9)
        for k in range(2 * n):
            xi[k] = _tab_beta(rng.random(), tabs[3], p[P_XI_A])  # (9)
    else:
        for k in range(2 * n):
            zeta[k] = rng.beta(2.0, p[P_ZETA_B])  # (9)
        for k in range(2 * n):
            xi[k] = rng.beta(p[P_XI_A], 2.0)  # (9)
    x = np.empty(2 * n)
    for k in range(2 * n):
        x[k] = rng.random()
    u_frac = np.empty(2 * n)
    for k in range(2 * n):
        u_frac[k] = rng.random()
    u_bond = np.empty(n)
    for k in range(n):
        u_bond[k] = rng.random()

    trapped = p[P_TRAPPED]
    sigma, sharp = p[P_SIGMA], p[P_SHARPNESS]
    s_eff, max_strain, eta = p[P_STRAIN_EFF], p[P_MAX_STRAIN], p[P_ETA_EQ]
    s_old = np.empty(2 * n)
    r_new = np.empty(2 * n)
    dud = np.empty(2 * n)
    frac = np.zeros(2 * n, dtype=np.bool_)
    n_frac = 0
    for k in range(n):
        ca = p[P_SQRT_A] * math.cos(phi[k])  # cos 2psi, as impacts.sample_impact_cos2psi
        sb = p[P_SQRT_B] * math.sin(phi[k])
        c2 = ca / math.sqrt(ca * ca + sb * sb)
        cos2 = c2 * c2  # cos^2 2psi, sin^2 2psi: events.impact_heats
        sin2 = 1.0 - cos2
        for side in range(2):
            q = k + side * n
            slot = i[k] if side == 0 else j[k]
            sq, rq = s[slot], r[slot]
            s_old[q] = sq
            e = u_in[k] * min(sq**2 / trapped, 1.0)  # (6)
            duf = e * sin2 * (1 - zeta[q] ** 2)  # (7)
            dup = e * cos2 * (1 - xi[q] ** 2)  # (8)
            dud[q] = duf + dup  # (10)
            area = pi / 4 * sq**2
            mag = min(s_eff * 1.5 * dup / (area * sq * sigma), max_strain)  # (11)
            c = math.sqrt(min(max(1 - (1 - rq) ** 2, 0.0), 1.0))
            eps = mag if c2 > -2.0 * c / (1.0 + c * c) else -mag  # (14): events.strain_sign
            rq = min(max(rq + (1 - rq) * c * eps, 0.0), R_MAX)  # (12), (13)
            rq = rq * math.exp(-eta * 1.5 * dup / (area * sq * sigma))  # rounding, after (13)
            r_new[q] = rq
            # fracture under the impact load: (20), (17)
            xq = x[q]
            pc = min(max(p[P_DELTA] * sq**2 / (1 - rq) * xq * (1 - xq), 0.0), 1.0)
            if u_frac[q] < pc:  # else no fracture whatever p_u <= 1: skip (17)
                dc = 2 * sq * math.sqrt(xq * (1 - xq))
                pu = _threshold(dud[q] / max(dc, 1e-300), p[P_U_FRAC], sharp)
                if u_frac[q] < pc * pu:
                    frac[q] = True
                    n_frac += 1

    # write back: shape change, then fragment 1 in place (order of Plant._impact_round)
    for k in range(n):
        r[i[k]] = r_new[k]
        r[j[k]] = r_new[n + k]
    s1 = np.empty(n_frac)
    r1 = np.empty(n_frac)
    s2 = np.empty(n_frac)
    r2 = np.empty(n_frac)
    dst = np.empty(n_frac, dtype=np.int64)
    f = 0
    for q in range(2 * n):
        if frac[q]:
            sq, rq, xq = s_old[q], r_new[q], x[q]
            dc = 2 * sq * math.sqrt(xq * (1 - xq))
            L = pi * sq / (1 - rq)  # (3)
            s1[f] = sq * math.sqrt(xq)  # (2)
            s2[f] = sq * math.sqrt(1 - xq)
            r1[f] = min(max(1 - pi * s1[f] / (xq * L + dc), 0.0), R_MAX)  # (4)
            r2[f] = min(max(1 - pi * s2[f] / ((1 - xq) * L + dc), 0.0), R_MAX)
            dst[f] = v[q % n]
            f += 1

    # bonding of i with j if neither broke: (15)-(18)
    bond = np.zeros(n, dtype=np.bool_)
    s_b = np.empty(n)
    r_b = np.empty(n)
    n_bond = 0
    for k in range(n):
        if frac[k] or frac[n + k]:
            continue
        si, sj, ri, rj = s_old[k], s_old[n + k], r_new[k], r_new[n + k]
        pb = min(max(p[P_GAMMA] * si * sj / ((1 - ri) * (1 - rj)), 0.0), 1.0)  # (15)
        if u_bond[k] >= pb:  # no bond whatever p_u <= 1: skip (16), (17)
            continue
        d = 0.75 * si * sj / (si + sj) * math.sqrt(3 * pi * u_in[k] / (p[P_MODULUS] * (si * si * si + sj * sj * sj)))  # (16)
        d = min(d, pi / 2 * min(si, sj))
        pu = _threshold((dud[k] + dud[n + k]) / d, p[P_U_BOND], sharp)  # (17)
        if u_bond[k] < pb * pu:
            bond[k] = True
            sb = math.sqrt(si**2 + sj**2)  # (18), (2)
            denom = si / (1 - ri) + sj / (1 - rj) - 2 * d / pi  # (4)
            s_b[n_bond] = sb
            r_b[n_bond] = min(max(1 - sb / max(denom, 1e-300), 0.0), R_MAX)
            n_bond += 1
    free = np.empty(n_bond, dtype=np.int64)
    src = np.empty(n_bond, dtype=np.int64)
    b = 0
    for k in range(n):
        if bond[k]:
            s[i[k]] = s_b[b]
            r[i[k]] = r_b[b]
            free[b] = j[k]
            src[b] = v[k]
            b += 1
    f = 0
    for q in range(2 * n):
        if frac[q]:
            slot = i[q] if q < n else j[q - n]
            s[slot] = s1[f]
            r[slot] = r1[f]
            f += 1

    # constant-number step (Plant._rebalance)
    kk = min(n_bond, n_frac)
    for t in range(kk):
        s[free[t]] = s2[t]
        r[free[t]] = r2[t]
    if n_bond > kk:  # more bonds: copies of the clone sources fill the free slots
        m = n_bond - kk
        cs = np.empty(m)
        cr = np.empty(m)
        for t in range(m):
            cs[t] = s[src[kk + t]]
            cr[t] = r[src[kk + t]]
        for t in range(m):
            s[free[kk + t]] = cs[t]
            r[free[kk + t]] = cr[t]
    elif n_frac > kk:  # more fractures: the extra fragments replace the particles in their victim slots
        m = n_frac - kk
        d_slots = dst[kk:].copy()
        twice = np.zeros(m, dtype=np.bool_)
        for t in range(m):
            if seen[d_slots[t]]:
                twice[t] = True
            seen[d_slots[t]] = True
        for t in range(m):
            seen[d_slots[t]] = False
        M = s.size
        for t in range(m):
            if twice[t]:
                d_slots[t] = rng.integers(0, M)
        for t in range(m):
            s[d_slots[t]] = s2[kk + t]
            r[d_slots[t]] = r2[kk + t]
    return n_bond, n_frac


@njit(cache=True)
def impacts(rng, s, r, qi, qj, qv, n, flush, p, seen, tabs):
    """Queue n new impacts, then run the first round (every round with ``flush``): Plant._impacts.

    Parameters
    ----------
    rng : numpy.random.Generator
        The plant's generator.
    s, r : ndarray
        The particles' sizes (m) and aspect ratios, changed in place.
    qi, qj, qv : ndarray of int64
        The impacts still queued.
    n : int
        Number of new impacts.
    flush : bool
        Run rounds until the queue is empty.
    p : ndarray
        Float parameters (``P_*`` indices).
    seen : ndarray of bool, shape (M,)
        All False; scratch space, left all False.
    tabs : tuple of four ndarrays
        The sampler tables (``Plant._sampler_tables``): energy main and tail, Beta(alpha + 1, 2),
        Beta(beta + 1, 2); unused with ``p[P_TABULATED] == 0``.

    Returns
    -------
    qi, qj, qv, impacts, bonds, fractures
    """
    M = s.size
    nq = qi.size
    i = np.empty(nq + n, dtype=np.int64)
    j = np.empty(nq + n, dtype=np.int64)
    v = np.empty(nq + n, dtype=np.int64)
    i[:nq] = qi
    j[:nq] = qj
    v[:nq] = qv
    # vector draws: numpy's stream, and 6x faster in numba than one integer at a time
    i[nq:] = rng.integers(0, M, n)
    j[nq:] = (i[nq:] + rng.integers(1, M, n)) % M  # uniform over the others
    v[nq:] = (j[nq:] + rng.integers(1, M, n)) % M  # rebalancing slot, never j
    n_imp, n_bond, n_frac = 0, 0, 0
    while i.size:
        ready = _first_round(i, j, v, seen)
        b, f = _round(rng, s, r, i[ready], j[ready], v[ready], p, seen, tabs)
        n_imp += int(ready.sum())
        n_bond += b
        n_frac += f
        rest = ~ready
        i, j, v = i[rest], j[rest], v[rest]
        if not flush:
            break
    return i, j, v, n_imp, n_bond, n_frac


@njit(cache=True)
def run_steps(rng, s, r, qi, qj, qv, lam, p, seen, n_new, flush, tabs):
    """The time steps of one milling interval (Plant._run): Poisson(lam[k]) new impacts per step, then the flush.

    Without steps (``lam`` empty): ``n_new`` new impacts and one round, every round with
    ``flush`` (Plant._impacts).

    Parameters
    ----------
    rng, s, r, qi, qj, qv, seen, tabs
        As :func:`impacts`.
    lam : ndarray, shape (K,)
        Mean number of new impacts of each step.
    p : ndarray, shape (K + 1, N_PARAMS)
        Float parameters of each step (temperature and hardening at its start), the last row for the flush.
    n_new : int
        New impacts when there are no steps.
    flush : bool
        Run every round when there are no steps.

    Returns
    -------
    qi, qj, qv, impacts, bonds, fractures
    """
    K = lam.size
    if K == 0:
        return impacts(rng, s, r, qi, qj, qv, n_new, flush, p[0], seen, tabs)
    n_imp, n_bond, n_frac = 0, 0, 0
    for k in range(K + 1):
        n = rng.poisson(lam[k]) if k < K else 0
        qi, qj, qv, a, b, f = impacts(rng, s, r, qi, qj, qv, n, k == K, p[k], seen, tabs)
        n_imp += a
        n_bond += b
        n_frac += f
    return qi, qj, qv, n_imp, n_bond, n_frac


# --- compiled-code cache ---------------------------------------------------------------------------

_LOCK_STALE_S = 900.0  # a compile lock older than this is a dead compile's


def cache_is_warm() -> bool:
    """Whether this machine's on-disk cache holds the compiled entry points (no compile on first call).

    Reads numba's cache index (which numba invalidates when this file changes); if numba's
    internals differ from the ones this reads, answers True (the first call then compiles in-process).
    """
    try:
        magic = run_steps.targetctx.codegen().magic_tuple()
        return any(key[1] == magic for key in run_steps._cache._cache_file._load_index())
    except Exception:  # pragma: no cover - other numba versions
        return True


def _lock_path() -> str:
    import hashlib
    import tempfile

    tag = hashlib.sha1(__file__.encode()).hexdigest()[:12]
    return os.path.join(tempfile.gettempdir(), f"bmctl-plant-compile-{tag}.lock")


def _state_dir() -> str:
    """bmctl's own cache folder, ``$XDG_CACHE_HOME/bmctl`` (``~/.cache/bmctl`` when unset)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "bmctl")


def _install_tag() -> str:
    """This install's compile inputs: the path and stamp of this file, bmctl's, numba's and Python's versions."""
    import hashlib
    import sys

    import numba

    from .. import __version__

    path = os.path.abspath(__file__)
    try:
        st = os.stat(path)
        stamp = f"{st.st_mtime_ns} {st.st_size}"
    except OSError:  # pragma: no cover
        stamp = ""
    key = "\0".join((path, stamp, __version__, numba.__version__, sys.version))
    return hashlib.sha1(key.encode()).hexdigest()[:12]


def failure_path() -> str:
    """The file that records a failed background compile of this install (:func:`compile_failure`)."""
    return os.path.join(_state_dir(), f"plant-compile-{_install_tag()}.failed")


def compile_failure() -> str | None:
    """The last line of the error of this install's failed background compile, or None.

    While it is recorded, no process starts another background compile (the plant keeps the
    numpy code, same results); ``python -m bmctl.plant._compiled`` compiles in the foreground,
    shows the whole error, and clears the record when it succeeds.
    """
    try:
        with open(failure_path(), encoding="utf-8", errors="replace") as fh:
            lines = [line.strip() for line in fh.read().splitlines() if line.strip()]
    except OSError:
        return None
    return lines[-1] if lines else "(no message)"


def _record_failure(text: str) -> None:
    """Keep ``text`` (a traceback) as this install's compile failure; quietly nothing if the folder is unwritable."""
    path = failure_path()
    tmp = f"{path}.{os.getpid()}.tmp"
    try:
        os.makedirs(os.path.dirname(path), mode=0o700, exist_ok=True)
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except OSError:  # pragma: no cover
        try:
            os.remove(tmp)
        except OSError:
            pass


def _clear_failure() -> None:
    try:
        os.remove(failure_path())
    except OSError:
        pass


_NOTED = {"failure": False}


def _note_failure(line: str) -> None:
    """One line on stderr, once per process: the compiled engine is off, and why."""
    import sys

    if _NOTED["failure"]:
        return
    _NOTED["failure"] = True
    print(f"bmctl: note: the compiled plant engine could not be built ({line}); the plant runs the numpy code "
          f"(same results, slower). Details: {failure_path()}; to retry: python -m bmctl.plant._compiled",
          file=sys.stderr)


def compile_in_background() -> bool:
    """Start one detached process that compiles the kernels into the cache (a lock file keeps it to one).

    Not after a failed compile of this install (:func:`compile_failure`): a note on stderr says so instead.
    Returns whether a compile process was started now.
    """
    import subprocess
    import sys
    import time

    failed = compile_failure()
    if failed is not None:
        _note_failure(failed)
        return False
    lock = _lock_path()
    try:
        if time.time() - os.path.getmtime(lock) > _LOCK_STALE_S:
            os.remove(lock)
    except OSError:
        pass
    try:
        os.close(os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
    except OSError:
        return False  # another process is compiling
    try:
        subprocess.Popen([sys.executable, "-m", "bmctl.plant._compiled", lock], start_new_session=True,
                         stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                         cwd=os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
    except OSError:  # pragma: no cover
        os.remove(lock)
        return False
    return True


def warmup_card():
    """A small valid card, built in code, for the warm-up run.

    The compiled code depends on the arguments' types only, which every card gives alike, so the
    warm-up needs no card file (``models/`` is not part of an installed package).
    """
    from ..config import CardInfo, ModelCard, Process, Stochastic

    return ModelCard(card=CardInfo(name="compile-warm-up"), process=Process(rpm=300.0),
                     stochastic=Stochastic(alpha=2.1, beta=1.8, gamma_per_um2=1.82e-4, delta_per_um2=8.1e-4))


def compile_now() -> None:
    """Compile (or load from the cache) the entry point, in this process, by running a small plant."""
    from . import plant as plant_module
    from .plant import Plant

    plant_module._READY["warm"] = True
    plant = Plant(warmup_card(), np.random.default_rng(0), 64, engine="numba")
    plant._run_compiled(_kin(plant), [(1.0, plant._step_params())])


def _main(argv: list[str]) -> int:
    """``python -m bmctl.plant._compiled [LOCKFILE]``: compile into the cache; the background compile passes its lock.

    A failure is recorded (:func:`compile_failure`); a success clears the record. Returns the exit status.
    """
    import traceback

    try:
        compile_now()
        if not cache_is_warm():
            raise RuntimeError("compiled, but numba's on-disk cache stayed cold (is the package folder or "
                               "$NUMBA_CACHE_DIR writable?)")
    except Exception:  # not an interrupt: that is no reason to stop retrying
        _record_failure(traceback.format_exc())
        if not argv:  # in the foreground: show the error
            raise
        return 1
    finally:
        if argv:
            try:
                os.remove(argv[0])
            except OSError:
                pass
    _clear_failure()
    if not argv:
        print("bmctl: the compiled plant engine is in the cache")
    return 0


def _kin(plant):
    from .kinematics import kinematics

    return kinematics(plant.card, plant.card.process.rpm)


if __name__ == "__main__":  # the background compile: python -m bmctl.plant._compiled LOCKFILE
    import sys

    os.nice(5)  # a background job: leave the cores to the user's runs
    # this file's kernels as bmctl.plant._compiled (numba caches them under the module's name, not __main__'s)
    from bmctl.plant._compiled import _main

    sys.exit(_main(sys.argv[1:]))
