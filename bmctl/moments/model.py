"""The moment model: :class:`MomentModel` and its factory :func:`make_moment_model`.

State  x = (s_mean_um, s_std_um, r_mean, r_std, temperature_c, hardening)
Input  u = (rpm, milling)        milling in [0, 1]: share of an interval spent milling
Param  p = (gamma_mult, delta_mult): the plant's gamma and delta factors relative to the card (default 1)

The equations are in :mod:`bmctl.moments.equations` (one definition for numpy and
casadi); docs/moments.md derives them and lists where they break.
"""

from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..config import ModelCard, load_card
from ..errors import InputError
from ..limits import INPUT_ROUNDING, rpm_rounding
from . import coeffs as cf
from . import equations as eq
from ..stats import law_size_stats
from .physics import Constants, constants, derived_threshold_laws

STATE_NAMES = ("s_mean_um", "s_std_um", "r_mean", "r_std", "temperature_c", "hardening")
INPUT_NAMES = ("rpm", "milling")
PARAM_NAMES = ("gamma_mult", "delta_mult")
#: the optional third multiplier: the mill's impact energy per particle against the card's (e_max)
ENERGY_NAME = "energy_mult"
#: absolute zero (degC): no state's temperature lies below it
ABSOLUTE_ZERO_C = -273.15
MAX_SUBSTEP_H = 0.0625  # RKC substep of the milling phase (accuracy of the fast modes at top speed)
STIFFNESS_PER_IMPACT = 2.0  # bound on |eigenvalue| of the z field per impact (measured ~1.4)


def n_substeps(dt_h: float) -> int:
    """Substeps for an interval of ``dt_h`` hours (substep <= MAX_SUBSTEP_H)."""
    return max(1, int(math.ceil(dt_h / MAX_SUBSTEP_H - 1e-9)))


def rkc_stages(rate_max_per_h: float, sub_h: float) -> int:
    """RKC2 stages whose stability interval covers the stiffest mode at the top speed (80 % margin)."""
    need = STIFFNESS_PER_IMPACT * rate_max_per_h * sub_h / 0.8
    s = 2
    while (2.0 / 3.0) * (s * s - 1) * (1 - 4.0 / 195.0) < need:
        s += 1
    return s


def _hours(dt_h) -> float:
    """``dt_h`` as a float, a value that is not a number named (``float(None)`` named nothing)."""
    if isinstance(dt_h, bool) or not isinstance(dt_h, (int, float, np.integer, np.floating)):
        raise TypeError(f"dt_h: must be a number of hours (got {type(dt_h).__name__})")
    return float(dt_h)


class MomentModel:
    """Moment model of the milled powder: size and shape moments, vial temperature, hardening.

    Build with :func:`make_moment_model`. Arrays of states are ``(..., 6)``; inputs
    ``(..., 2)``; parameters ``(..., 2)`` (batches broadcast, e.g. a particle filter's cloud).

    Attributes
    ----------
    card : ModelCard
    const : Constants
        Card-derived scalars (physics.py).
    coeffs : dict
        Identified (or default) coefficients.
    coeffs_source : str
        Where the coefficients came from ("defaults" or a file path).
    """

    nx, nu, np = 6, 2, 2
    state_names = STATE_NAMES
    input_names = INPUT_NAMES
    param_names = PARAM_NAMES

    def __init__(self, card: ModelCard, coeffs: dict[str, float], coeffs_source: str = "defaults"):
        self.card = card
        self.const: Constants = constants(card)
        self.coeffs = dict(coeffs)
        self.coeffs_source = coeffs_source
        self._ca_steps: dict = {}
        self._ca_sims: dict = {}

    # --- basics --------------------------------------------------------------------------------
    @property
    def rpm_max(self) -> float:
        return self.const.rpm_max

    def x0(self) -> np.ndarray:
        """Initial state from the card: powder moments (r ~ exponential: std = mean), ambient T, h = 0."""
        c = self.const
        return np.array([c.s0_mean_um, c.s0_std_um, c.r0_mean, c.r0_mean, c.ambient_C, 0.0])

    def p0(self) -> np.ndarray:
        """Nominal parameters (gamma_mult, delta_mult) = (1, 1)."""
        return np.ones(2)

    def _p(self, p):
        return self.p0() if p is None else np.asarray(p, dtype=float)

    # --- dynamics (numpy) ---------------------------------------------------------------------
    def rhs(self, x, u, p=None, xp=None):
        """dx/dt (per hour), duty-averaged over the milling fraction.

        ``xp=numpy``: arrays ``(..., 6)`` in, ``(..., 6)`` out. ``xp=casadi``: casadi
        column vectors (SX/MX/DM) in, a column vector out.

        Raises
        ------
        bmctl.errors.InputError
            numpy: as :meth:`step` (casadi symbols are not checked).
        """
        B = eq.NP if xp is None else eq.backend(xp)
        if B is eq.NP:
            x, u = self._checked(x, u, p)
            p = _arr(self._p(p))
            out = eq.rhs(B, self.const, self.coeffs, _cols(x), _cols(u), _cols(p))
            return B.stack(out)
        p = self.p0() if p is None else p
        return B.stack(eq.rhs(B, self.const, self.coeffs, _ca_cols(x, 6), _ca_cols(u, 2), _ca_cols(p, 2)))

    def step(self, x, u, dt_h: float, p=None, substeps: int | None = None) -> np.ndarray:
        """Next state after ``dt_h`` hours: mill ``milling * dt_h`` at rpm, then rest.

        Parameters
        ----------
        x : array_like, (..., 6)
        u : array_like, (..., 2)
            (rpm, milling); rpm in [0, rpm_max], milling in [0, 1] (each within a solver's rounding,
            :data:`bmctl.limits.INPUT_ROUNDING`; farther out, or another shape, is refused).
        dt_h : float
            Interval length (h), > 0.
        p : array_like, (..., 2) or (..., 3), optional
            (gamma_mult, delta_mult[, energy_mult]), finite and >= 0; default (1, 1).
        substeps : int, optional
            RKC substeps of the milling phase (default: substeps of <= 1/16 h over ``dt_h``); the
            stages follow from the stiffness.

        Raises
        ------
        bmctl.errors.InputError
            ``x`` not finite, with hardening outside [0, 1] or a temperature below absolute zero;
            ``u`` out of range; ``p`` not finite, negative or of another shape; ``dt_h`` not > 0.
        """
        x, u = self._checked(x, u, p)
        return self._step(x, u, dt_h, p, substeps)

    def _checked(self, x, u, p) -> tuple[np.ndarray, np.ndarray]:
        """``x`` and ``u`` as arrays, refused as :meth:`step` says (``p`` checked where given)."""
        x, u = _arr(x), _arr(u)
        self._check_state(x, "x")
        self._check_values(x, "x")
        self._check_inputs(u, "u")
        if p is not None:
            self._check_params(p, "p")
        return x, u

    def _step(self, x: np.ndarray, u: np.ndarray, dt_h: float, p=None, substeps: int | None = None) -> np.ndarray:
        """:meth:`step` of checked arrays."""
        dt_h = _hours(dt_h)
        p = _arr(self._p(p))
        n, st = self._integration(dt_h)
        if substeps is not None and substeps != n:
            from ..errors import require_whole

            n = require_whole(substeps, "substeps", 1)  # 2.7 was cut to 2
            st = rkc_stages(self.const.rate_max_per_h, dt_h / n)
        out = eq.step(eq.NP, self.const, self.coeffs, _cols(x), _cols(u), _cols(p), dt_h, n, st)
        return eq.NP.stack(out)

    def simulate(self, x0, U, dt_h: float, p=None) -> np.ndarray:
        """States over a piecewise-constant input sequence.

        Parameters
        ----------
        x0 : array_like, (6,)
        U : array_like, (K, 2)
            (rpm, milling) per interval; rpm in [0, rpm_max], milling in [0, 1] (each within a
            solver's rounding, :data:`bmctl.limits.INPUT_ROUNDING`; farther out, or another shape,
            is refused).
        dt_h : float
            Interval length (h).
        p : array_like, (2,) or (3,), optional
            (gamma_mult, delta_mult[, energy_mult]), finite and >= 0; default (1, 1).

        Returns
        -------
        ndarray, (K + 1, 6)
            x0 first. Single trajectories use the compiled casadi step (same math, faster).

        Raises
        ------
        bmctl.errors.InputError
            As :meth:`step` (``x0`` for ``x``, ``U`` for ``u``).
        """
        U = np.atleast_2d(np.asarray(U, dtype=float))
        x0 = np.asarray(x0, dtype=float)
        dt_h = _hours(dt_h)
        self._integration(dt_h)  # dt_h > 0 and finite, even for an empty U
        self._check_state(x0, "x0")
        self._check_values(x0, "x0")
        if p is not None:
            self._check_params(p, "p")
        if U.ndim != 2 or U.shape[1] != 2:
            raise InputError(f"U: must be (rpm, milling) per interval, shape (K, 2) (got shape {U.shape})")
        self._check_inputs(U, "U")
        if U.shape[0] == 0:
            return x0[None].copy()
        pp = self._p(p)
        if x0.ndim == 1 and pp.ndim == 1 and pp.shape[0] == 2:
            F = self._casadi_sim(float(dt_h), U.shape[0])
            X = np.asarray(F(x0, U.T, pp)).T
            return np.vstack([x0[None, :], X])
        out = [x0]
        for k in range(U.shape[0]):
            out.append(self._step(out[-1], U[k], dt_h, pp))
        return np.stack(out)

    def _check_state(self, x: np.ndarray, name: str) -> None:
        """Refuse a state array that is not ``(..., 6)``, naming it."""
        if x.ndim == 0 or x.shape[-1] != self.nx:
            raise InputError(f"{name}: must be a state {STATE_NAMES} of shape (..., {self.nx}) (got shape {x.shape})")

    def _check_values(self, x: np.ndarray, name: str) -> None:
        """Refuse a state array of shape ``(..., 6)`` that is not finite, has hardening outside [0, 1]
        or a temperature below absolute zero, naming it (plain float comparisons for one state)."""
        if x.size == 0:
            return
        if x.ndim == 1:
            v = x.tolist()
            if all(map(math.isfinite, v)) and 0.0 <= v[5] <= 1.0 and v[4] >= ABSOLUTE_ZERO_C:
                return
        else:  # whole-array and column reductions (a reduction along the batch axis is ~10x slower)
            h = x[..., 5]
            if (-math.inf < float(x.min()) and float(x.max()) < math.inf and float(h.min()) >= 0.0
                    and float(h.max()) <= 1.0 and float(x[..., 4].min()) >= ABSOLUTE_ZERO_C):  # NaN fails too
                return

        def where(idx) -> str:
            return f"{name}[{', '.join(str(int(i)) for i in idx)}]" if idx else name

        bad = ~np.isfinite(x)
        if np.any(bad):
            idx = np.unravel_index(int(np.argmax(bad)), bad.shape)
            raise InputError(f"{where(idx[:-1])}: {STATE_NAMES[idx[-1]]} must be finite (got {float(x[idx]):g})")
        h, T = x[..., 5], x[..., 4]
        for bad, col, what in ((~((h >= 0.0) & (h <= 1.0)), 5, "must be in [0, 1]"),
                               (T < ABSOLUTE_ZERO_C, 4, f"must be >= {ABSOLUTE_ZERO_C:g} °C (absolute zero)")):
            if np.any(bad):
                idx = np.unravel_index(int(np.argmax(bad)), bad.shape) if bad.ndim else ()
                raise InputError(f"{where(idx)}: {STATE_NAMES[col]} {what} (got {float(x[idx + (col,)]):g})")

    def _check_params(self, p, name: str) -> np.ndarray:
        """Refuse multipliers that are not ``(..., 2)`` or ``(..., 3)`` (gamma_mult, delta_mult[, energy_mult])
        or not finite and >= 0, naming them; returns them as an array."""
        p = _arr(p)
        if p.ndim == 0 or p.shape[-1] not in (2, 3):
            raise InputError(f"{name}: must be (gamma_mult, delta_mult[, energy_mult]) of shape (..., 2) or (..., 3) "
                             f"(got shape {p.shape})")
        if p.size == 0:
            return p
        if p.ndim == 1:
            if all(0.0 <= v < math.inf for v in p.tolist()):  # NaN fails too
                return p
        elif 0.0 <= float(p.min()) and float(p.max()) < math.inf:
            return p
        bad = ~((p >= 0.0) & (p < math.inf))
        idx = np.unravel_index(int(np.argmax(bad)), bad.shape)
        where = f"{name}[{', '.join(str(int(i)) for i in idx[:-1])}]" if p.ndim > 1 else name
        what = (PARAM_NAMES + (ENERGY_NAME,))[int(idx[-1])]
        raise InputError(f"{where}: {what} must be a finite number >= 0 (got {float(p[idx]):g})")

    def _check_point(self, x, u, p=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One state, one input and one (gamma_mult, delta_mult) checked as :meth:`step` checks them
        (a linearisation point); returns them as arrays (``p`` None: :meth:`p0`)."""
        x, u = _arr(x), _arr(u)
        if x.shape != (self.nx,):
            raise InputError(f"x: must be one state {STATE_NAMES} of shape ({self.nx},) (got shape {x.shape})")
        self._check_values(x, "x")
        if u.shape != (self.nu,):
            raise InputError(f"u: must be one (rpm, milling) of shape ({self.nu},) (got shape {u.shape})")
        self._check_inputs(u, "u")
        if p is None:
            return x, u, self.p0()
        p = self._check_params(p, "p")
        if p.shape != (2,):
            raise InputError(f"p: must be (gamma_mult, delta_mult) of shape (2,) (got shape {p.shape})")
        return x, u, p

    def _check_inputs(self, u: np.ndarray, name: str) -> None:
        """Refuse inputs that are not ``(..., 2)`` or have rpm outside [0, rpm_max] or milling
        outside [0, 1] by more than a solver's rounding (plain float comparisons for one input)."""
        if u.ndim == 0 or u.shape[-1] != self.nu:
            raise InputError(f"{name}: must be (rpm, milling) of shape (..., {self.nu}) (got shape {u.shape})")
        if u.size == 0:
            return
        top = self.const.rpm_max
        tol = rpm_rounding(top)
        if u.ndim == 1:
            lo_r, lo_m = hi_r, hi_m = float(u[0]), float(u[1])
        else:
            (lo_r, lo_m), (hi_r, hi_m) = u.min(axis=tuple(range(u.ndim - 1))), u.max(axis=tuple(range(u.ndim - 1)))
        if -tol <= lo_r and hi_r <= top + tol and -INPUT_ROUNDING <= lo_m and hi_m <= 1.0 + INPUT_ROUNDING:
            return
        rpm, m = u[..., 0], u[..., 1]
        bad_r = ~((rpm >= -tol) & (rpm <= top + tol))
        bad_m = ~((m >= -INPUT_ROUNDING) & (m <= 1.0 + INPUT_ROUNDING))
        for bad, what, rng, v in ((bad_r, "rpm", f"[0, {top:g}] (the card's mill.rpm_max)", rpm),
                                  (bad_m, "milling", "[0, 1]", m)):
            if np.any(bad):
                idx = np.unravel_index(int(np.argmax(bad)), bad.shape) if bad.ndim else ()
                where = f"{name}[{', '.join(str(int(i)) for i in idx)}]" if idx else name
                raise InputError(f"{where}: {what} must be a number in {rng} (got {float(v[idx]):g})")

    def event_counts(self, x0, U, dt_h: float, p=None) -> np.ndarray:
        """Bonding and fracture events per particle in each interval of a simulated trajectory.

        The plant's ``bond_events`` and ``fracture_events`` divided by its particle count:
        eqns (15)-(19) and (20) averaged over the closed-form laws (the rates whose difference
        is d ln N / dt), integrated over each interval's milling time alongside the moments.

        Parameters
        ----------
        x0 : array_like, (6,)
            Initial state.
        U : array_like, (K, 2)
            (rpm, milling) per interval.
        dt_h : float
            Interval length (h).
        p : array_like, (2,), optional
            (gamma_mult, delta_mult); default (1, 1).

        Returns
        -------
        ndarray, (K, 2)
            (bonds, fractures) per particle in each interval.

        Raises
        ------
        bmctl.errors.InputError
            As :meth:`simulate` (``x0`` of shape (6,), ``p`` of shape (2,) or (3,)).

        Examples
        --------
        >>> from bmctl.moments.model import make_moment_model
        >>> mm = make_moment_model("models/alni-1to1-300rpm-lab.toml")
        >>> C = mm.event_counts(mm.x0(), [[300.0, 1.0], [0.0, 1.0]], 1.0)
        >>> bool(C[0, 0] > 1 and C[1, 0] < 1e-4)  # the rest: none (the rates are smooth at rpm 0)
        True
        """
        dt_h = _hours(dt_h)
        U = np.atleast_2d(np.asarray(U, dtype=float))
        x0 = np.asarray(x0, dtype=float)
        if x0.shape != (self.nx,):
            raise InputError(f"x0: must be one state {STATE_NAMES} of shape ({self.nx},) (got shape {x0.shape})")
        self._check_values(x0, "x0")
        if p is not None and self._check_params(p, "p").ndim != 1:
            raise InputError(f"p: must be one (gamma_mult, delta_mult[, energy_mult]) of shape (2,) or (3,) "
                             f"(got shape {_arr(p).shape})")
        if U.ndim != 2 or U.shape[1] != 2:
            raise InputError(f"U: must be (rpm, milling) per interval, shape (K, 2) (got shape {U.shape})")
        self._check_inputs(U, "U")
        x, pp = list(x0), list(self._p(p))
        n, st = self._integration(dt_h)
        out = []
        for u in U:
            z = eq.step(eq.NP, self.const, self.coeffs, x, list(u), pp, dt_h, n, st, events=True)
            x = z[:6]
            out.append([float(v) for v in z[6:]])
        return np.array(out).reshape(-1, 2)

    def _integration(self, dt_h: float) -> tuple[int, int]:
        """(substeps, RKC stages) for an interval of ``dt_h`` hours."""
        if not (dt_h > 0 and math.isfinite(dt_h)):
            raise InputError(f"dt_h: must be a finite number > 0 (got {dt_h})")
        n = n_substeps(dt_h)
        return n, rkc_stages(self.const.rate_max_per_h, dt_h / n)

    # --- casadi --------------------------------------------------------------------------------
    def casadi_step(self, dt_h: float, substeps: int | None = None):
        """casadi.Function ``F(x[6], u[2], p[2]) -> x_next[6]`` over ``dt_h`` hours (SX, cached).

        ``substeps`` overrides the number of RKC substeps (default: substeps of <= 1/16 h); the
        stages follow from the stiffness, so a coarser step stays stable but is less accurate.
        """
        n_default, _ = self._integration(float(dt_h))
        n = n_default if substeps is None else int(substeps)
        if n < 1:
            raise InputError(f"substeps: must be >= 1 (got {substeps})")
        key = round(float(dt_h), 12) if n == n_default else (round(float(dt_h), 12), n)
        if key not in self._ca_steps:
            import casadi as ca

            x = ca.SX.sym("x", 6)
            u = ca.SX.sym("u", 2)
            p = ca.SX.sym("p", 2)
            s = rkc_stages(self.const.rate_max_per_h, float(dt_h) / n)
            out = eq.step(eq.CA(), self.const, self.coeffs, _ca_cols(x, 6), _ca_cols(u, 2), _ca_cols(p, 2),
                          float(dt_h), n, s, rates=self._casadi_rates())
            self._ca_steps[key] = ca.Function("moment_step", [x, u, p], [ca.vertcat(*out)],
                                              ["x", "u", "p"], ["x_next"])
        return self._ca_steps[key]

    def _casadi_rates(self):
        """The particle field (:meth:`rate_function`), wrapped to take and return lists."""
        self.rate_function()
        return self._ca_steps["rates"][1]

    def rate_function(self):
        """casadi.Function ``rates(y[4], a[5]) -> dy/dt[4]``: the particle field (cached).

        ``y`` are the integration coordinates (ln E[s], ln E[s^2], E[r], E[r^2]) and ``a`` =
        (T, h, rpm / rpm_max, gamma_mult, delta_mult). :meth:`casadi_step` evaluates it at every
        RKC stage, so its ``n_instructions()`` is the measure of the model's cost that
        ``benchmarks/bench_moments.py`` prints.

        Examples
        --------
        >>> from bmctl.moments import make_moment_model
        >>> m = make_moment_model("models/alni-1to1-300rpm-lab.toml")
        >>> m.rate_function().n_in(), m.rate_function().n_out()
        (2, 1)
        """
        if "rates" not in self._ca_steps:
            self._ca_steps["rates"] = eq.casadi_rate_field(self.const, self.coeffs)  # (Function, list wrapper)
        return self._ca_steps["rates"][0]

    def casadi_rhs(self):
        """casadi.Function ``f(x, u, p) -> dx/dt`` (per hour)."""
        import casadi as ca

        x, u, p = ca.SX.sym("x", 6), ca.SX.sym("u", 2), ca.SX.sym("p", 2)
        return ca.Function("moment_rhs", [x, u, p], [self.rhs(x, u, p, xp=ca)], ["x", "u", "p"], ["xdot"])

    def _casadi_sim(self, dt_h: float, K: int):
        key = (round(dt_h, 12), K)
        if key not in self._ca_sims:
            self._ca_sims[key] = self.casadi_step(dt_h).mapaccum("sim", K, [0], [0])
            if len(self._ca_sims) > 16:
                self._ca_sims.pop(next(iter(self._ca_sims)))
        return self._ca_sims[key]

    # --- outputs -------------------------------------------------------------------------------
    def distributions(self, x):
        """The s and r laws implied by a state: (log-normal s in um, Beta r) as scipy frozen objects.

        The moments are first projected onto realisable sets (equations.project).
        Batched states give frozen objects with array parameters.
        """
        from scipy import stats

        sig, mu, a, b = self.distribution_params(x)
        return stats.lognorm(s=sig, scale=np.exp(mu)), stats.beta(a, b)

    def distribution_params(self, x):
        """(sigma_ln, mu_ln, beta_a, beta_b) of the s and r laws of a state (arrays broadcast)."""
        x = _arr(x)
        m, sd, rm, rho = eq.project(eq.NP, _cols(x))
        var_ln = np.log1p((sd / m) ** 2)
        mu = np.log(m) - 0.5 * var_ln
        nu = 1.0 / (rho * rho) - 1.0  # a + b, from var = m(1-m)/(a+b+1)
        return np.sqrt(var_ln), mu, rm * nu, (1 - rm) * nu

    def loglik(self, x, s_um, r, r_floor: float = 0.005, s_floor_um: float = 0.5, sum_over=True):
        """Log-likelihood of measured particles (s_um, r) under the state's laws.

        s and r are taken as independent (the mean-field closure). Values of r below
        ``r_floor`` (round to the resolution of a perimeter measurement; the plant has
        many exact zeros) count as censored: log P(r < r_floor). Sizes below ``s_floor_um``
        likewise. Returns the sum over particles (``sum_over``) for each state in a batch,
        else the per-particle values ``(..., n)``.

        Raises
        ------
        bmctl.errors.InputError
            No measured particles, s_um and r of other shapes, not finite, s_um <= 0 or r outside [0, 1).
        """
        s_um = np.asarray(s_um, dtype=float)
        r = np.asarray(r, dtype=float)
        if s_um.shape != r.shape:
            raise InputError(f"loglik: s_um and r must have the same shape (got {s_um.shape} and {r.shape})")
        if not (np.all(np.isfinite(s_um)) and np.all(np.isfinite(r))):
            raise InputError("loglik: measured s_um and r must be finite")
        if s_um.size == 0:
            raise InputError("loglik: s_um, r: a sample needs one or more measured particles (got none)")
        for bad, what, v in ((~(s_um > 0), "s_um must be > 0", s_um),
                             (~((r >= 0) & (r < 1)), "r must be in [0, 1)", r)):
            if np.any(bad):
                k = int(np.argmax(bad))
                raise InputError(f"loglik: particle {k + 1}: {what} (got {float(v.flat[k]):g})")
        from scipy import special

        sig, mu, a, b = (v[..., None] for v in self.distribution_params(x))
        ls = np.log(np.maximum(s_um, s_floor_um))
        z = (ls - mu) / sig
        ll_s = -0.5 * z * z - np.log(sig) - ls - 0.5 * math.log(2 * math.pi)
        low_s = s_um < s_floor_um
        if np.any(low_s):
            ll_s = np.where(low_s, special.log_ndtr((math.log(s_floor_um) - mu) / sig), ll_s)
        rc = np.clip(r, r_floor, 1 - 1e-6)
        ll_r = (a - 1) * np.log(rc) + (b - 1) * np.log1p(-rc) - special.betaln(a, b)
        low_r = r < r_floor
        if np.any(low_r):
            cens = np.log(np.maximum(special.betainc(a, b, r_floor), 1e-300))
            ll_r = np.where(low_r, cens, ll_r)
        ll = ll_s + ll_r
        return ll.sum(axis=-1) if sum_over else ll

    def outputs(self, x) -> dict:
        """Moments of a state as a dict (plant.moments() names; modes of the implied laws)."""
        x = _arr(x)
        sig, mu, a, b = self.distribution_params(x)
        r_mode = np.where((a > 1) & (b > 1), (a - 1) / np.maximum(a + b - 2, 1e-12), np.where(a <= 1, 0.0, 1.0))
        out = {
            "s_mean_um": x[..., 0], "s_std_um": x[..., 1], "s_mode_um": np.exp(mu - sig**2),
            "r_mean": x[..., 2], "r_std": x[..., 3], "r_mode": r_mode,
            "temperature_c": x[..., 4], "hardening": x[..., 5],
        }
        # volume-weighted d10/d50/d90/span, area-weighted mean/mode in closed form (bmctl.stats.law_size_stats)
        out.update(size_stats_of_state(x))
        return out

    def casadi_size_stats(self, x) -> dict:
        """:data:`bmctl.stats.SIZE_STAT_NAMES` of a casadi state (column vector) in closed form.

        The same closed form as :meth:`outputs` (:func:`bmctl.stats.law_size_stats` of the
        projected mean and std), as casadi expressions for targets on ``d50_um``, ``d90_um`` or
        ``span`` in an MPC cost.
        """
        B = eq.backend("casadi")
        m, sd, _, _ = eq.project(B, _ca_cols(x, 6)[:4])
        return law_size_stats(m, sd)

    # --- linear analysis -----------------------------------------------------------------------
    def linearize(self, x, u, p=None, dt_h: float | None = None):
        """Linearisation as a python-control ``StateSpace``.

        Continuous (per hour) from the duty-averaged field, or discrete with period
        ``dt_h`` from the step map. Outputs: the four micrograph moments
        (s_mean, s_std, r_mean, r_std). Inputs: (rpm, milling).
        """
        from .linear import linearize

        return linearize(self, x, u, p, dt_h)

    def __repr__(self) -> str:
        return f"MomentModel({self.card.card.name!r}, coeffs={self.coeffs_source!r})"


def size_stats_of_state(x) -> dict:
    """Volume-weighted D-values and span, area-weighted mean and mode of states ``(..., >=2)``.

    Read out in closed form from the projected number mean and std (``equations.project``) by
    :func:`bmctl.stats.law_size_stats`: a Weibull law of that mean and std (the particle filter's
    default likelihood law), whose D-values track the plant about twice as closely as the
    log-normal of the moment closure (docs/fidelity.md).
    """
    x = _arr(x)
    m, sd, _, _ = eq.project(eq.NP, [x[..., 0], x[..., 1], x[..., 2], x[..., 3]])
    return law_size_stats(m, sd)


def _arr(v) -> np.ndarray:
    return np.asarray(v, dtype=float)


def _cols(a: np.ndarray) -> list:
    return [a[..., i] for i in range(a.shape[-1])]


def _ca_cols(v, n: int) -> list:
    import casadi as ca

    if isinstance(v, (list, tuple, np.ndarray)):
        v = ca.DM(np.asarray(v, dtype=float).reshape(-1))
    if v.shape[0] != n:
        raise ValueError(f"expected a casadi vector of length {n} (got shape {v.shape})")
    return [v[i] for i in range(n)]


@lru_cache(maxsize=16)
def _derived(card_json: str) -> dict:
    return derived_threshold_laws(ModelCard.model_validate_json(card_json))


def default_coeffs(card: ModelCard) -> dict[str, float]:
    """Built-in coefficients: unit multipliers and the derived threshold laws of the card.

    Parameters
    ----------
    card : ModelCard
        The model card the threshold laws are derived from.
    """
    return cf.defaults(_derived(card.model_dump_json()))


def make_moment_model(card_or_path, coeffs: dict | str | Path | None = None) -> MomentModel:
    """Build the moment model of a model card.

    Parameters
    ----------
    card_or_path : ModelCard or path-like
        The card (``models/*.toml``).
    coeffs : dict, path-like or "defaults", optional
        Coefficients: a dict, a ``*.moments.toml`` file (used as given: missing names take the
        defaults), or ``"defaults"`` for the built-in defaults. Default: the identified file next
        to the card (``models/<name>.moments.toml``) when the card is given as a path, used only
        when it records this card's values (the check of :func:`bmctl.moments.for_card`;
        otherwise refused), or the built-in defaults when there is none. A card object needs
        ``coeffs``: its file is not known.

    Returns
    -------
    MomentModel

    Raises
    ------
    InputError
        The file next to the card was identified for other card values (or records none, or lacks
        coefficients), or a card object was given without ``coeffs``.

    Examples
    --------
    >>> from bmctl.moments import make_moment_model
    >>> model = make_moment_model("models/alni-1to1-300rpm-lab.toml")
    >>> x = model.x0()
    >>> X = model.simulate(x, [[300.0, 1.0]] * 12, dt_h=1.0)
    >>> X.shape
    (13, 6)
    >>> bool(X[-1, 4] > 50.0)   # the vial heats up at 300 rpm
    True
    """
    source = "defaults"
    if isinstance(card_or_path, ModelCard):
        card, card_path = card_or_path, None
        if coeffs is None:
            raise InputError(f"card {card.card.name}: make_moment_model: a card object does not say which card file, "
                             "and so which coefficients, it belongs to; pass the card's path (its "
                             "<card>.moments.toml is used) or coeffs= (a coefficient file, a dict or \"defaults\")")
    else:
        card_path = Path(card_or_path)
        card = load_card(card_path)
    if isinstance(coeffs, str) and coeffs == "defaults":
        coeffs = None
    elif coeffs is None and card_path is not None and cf.coeffs_path(card_path).exists():
        from .forcard import check_own

        coeffs = check_own(card, card_path, "make_moment_model").path
    table = default_coeffs(card)
    if isinstance(coeffs, (str, Path)):
        table.update(cf.load_coeffs(coeffs))
        source = str(coeffs)
    elif isinstance(coeffs, dict):
        table.update(cf.check(coeffs, "coeffs"))
        source = "dict"
    elif coeffs is not None:
        raise InputError(f"coeffs: must be a dict, a coefficient file or \"defaults\" (got {type(coeffs).__name__})")
    return MomentModel(card, table, source)
