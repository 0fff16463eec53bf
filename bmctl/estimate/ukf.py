"""An unscented Kalman filter on the moment model: the estimator baseline of the particle filter.

Same model, same measurement model, same state and the same public API as
:class:`bmctl.estimate.filter.ParticleFilter` (``predict``, ``update``, ``estimate``), so either
can run a trial or ``bmctl estimate``. Built on ``filterpy.kalman.UnscentedKalmanFilter`` with
``MerweScaledSigmaPoints`` (van der Merwe 2004).

Filter state (8): z = (ln s_mean_um, ln s_std_um, ln r_mean, ln r_std, temperature_c,
hardening, ln gamma_mult, ln delta_mult). The positive quantities are carried in log, so every
sigma point maps to positive moments and multipliers.

Propagation
    every sigma point through the moment model (batched: one ``model.step`` call for all
    2n + 1 points) under the applied (rpm, milling); the log multipliers take a random walk of
    std ``param_walk_per_sqrt_h * sqrt(dt)`` and the temperature one of
    ``temperature_noise_c_per_sqrt_h``. The model-discrepancy noise of the log moments,
    ``q * sqrt(tau)`` as in the particle filter, is added to the covariance when the sample
    arrives (tau: hours since the last update), after ``q`` has been adapted from the
    innovation (Mehra 1972, the particle filter's rule).
Update
    the measurement is the sample's own maximum-likelihood log moments
    (:func:`likelihood.fit_sample` under the stated size law and noise model) with covariance
    the inverse of the tempered observed information, ``(eta_b I_b)^-1`` per block (size,
    shape), ``eta`` from :func:`filter.learning_rates` (Lyddon-Holmes-Walker calibration and
    the law-misfit floor). That is the Gaussian (Laplace) approximation of the particle
    filter's tempered likelihood; h(z) = z[:4]. A block whose fit did not converge is left
    out of the update; a vial-temperature reading adds h(z) = z[4], variance
    ``sigma_temperature_c**2``.

Failure modes handled
    * non-positive-definite covariance (round-off, negative sigma weights, clipped sigma
      points): the covariance is symmetrised after every predict and update and, when its
      Cholesky factorisation fails, jitter ``eps * I`` is added, eps starting at
      ``jitter_rel`` times the mean variance and growing tenfold until it factorises
      (counted in ``n_repaired``);
    * state bounds: log coordinates for the positive quantities; the moments of every sigma
      point and of the posterior mean are projected onto the realisable set of the particle
      filter (:meth:`ParticleFilter._feasible`: r_mean < 0.9, Beta-feasible r_std, ...), the
      hardening is clipped to [0, 1], the log multipliers to +-``log_mult_max``;
    * a failed model step (non-finite) keeps that sigma point where it was.

Read-out: the mean and 90 % interval of each log quantity are those of the log-normal
marginal (mean exp(m + v/2), interval exp(m -+ 1.645 sqrt(v))); temperature and hardening
are Gaussian (m -+ 1.645 sqrt(v)). The filter draws no random numbers: the ``rng`` argument
is accepted for the common constructor and unused.
"""

from __future__ import annotations

import math

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter
from pydantic import Field, model_validator
from typing import Annotated

from ..config import Finite, NonNeg, Pos, Strict
from .filter import (N_MOMENTS, Estimate, ParticleFilter, check_predict, check_update, check_x0, learning_rates,
                     model_step)
from .likelihood import LawSettings, fit_sample

Z90 = 1.6448536269514722  # standard-normal 95 % quantile: the 90 % interval is m -+ Z90 sd
NZ = 8  # filter-state dimension
LOG_IDX = np.array([0, 1, 2, 3, 6, 7])  # components carried in log

FourPos = tuple[Pos, Pos, Pos, Pos]


class UKFSettings(Strict):
    """Unscented-Kalman-filter settings (dimensionless unless suffixed).

    Attributes
    ----------
    process_noise_per_sqrt_h : 4 floats > 0
        Model-discrepancy random walk of ln(s_mean, s_std, r_mean, r_std) per sqrt(hour)
        (the particle filter's defaults).
    adapt : bool
        Adapt the discrepancy noise from the innovations.
    adapt_rate : float in (0, 1]
        Share of the newest innovation in the adapted variance.
    process_noise_floor : 4 floats > 0
        Lower limits of the adapted noise.
    process_noise_max : float
        Upper limit of the adapted noise.
    temperature_noise_c_per_sqrt_h : float
        Random walk of the vial temperature (degC per sqrt(hour)).
    hardening_noise_per_sqrt_h : float
        Random walk of the hardening (keeps its variance off zero).
    param_prior_log_std : float
        Std of the initial log multipliers.
    param_walk_per_sqrt_h : float
        Random walk of the log multipliers per sqrt(hour).
    initial_spread : float
        Std of the initial log moments.
    initial_temperature_std_c : float
        Std of the initial temperature (degC).
    learning_rate, calibrate_learning_rate
        Power-likelihood learning rate as in the particle filter (:func:`learning_rates`).
    law : LawSettings
        Measurement laws, noise and raster.
    sigma_temperature_c : float
        Noise of a vial-temperature reading.
    alpha, beta, kappa : float
        Merwe scaled sigma points. The default (1, 2, 0) gives non-negative weights
        (points at +-sqrt(n) sd), so the predicted covariance stays positive semi-definite.
    jitter_rel : float
        First jitter (times the mean variance) added when a covariance does not factorise.
    log_mult_max : float
        Bound on |ln gamma_mult|, |ln delta_mult|.
    """

    process_noise_per_sqrt_h: FourPos = (0.15, 0.15, 0.8, 0.8)
    adapt: bool = True
    adapt_rate: Annotated[float, Field(gt=0, le=1)] = 0.3
    process_noise_floor: FourPos = (0.05, 0.08, 0.2, 0.2)
    process_noise_max: Pos = 1.5
    temperature_noise_c_per_sqrt_h: Pos = 1.0
    hardening_noise_per_sqrt_h: Pos = 1e-3
    param_prior_log_std: Pos = 0.4
    param_walk_per_sqrt_h: Pos = 0.01
    initial_spread: Pos = 0.02
    initial_temperature_std_c: Pos = 1.0
    learning_rate: Annotated[float, Field(gt=0, le=1)] = 1.0
    calibrate_learning_rate: bool = True
    law: LawSettings = LawSettings()
    sigma_temperature_c: Pos = 2.0
    alpha: Annotated[float, Field(gt=0, le=1)] = 1.0
    beta: NonNeg = 2.0
    kappa: Finite = 0.0
    jitter_rel: Annotated[float, Field(gt=0, lt=1)] = 1e-9
    log_mult_max: Pos = math.log(20.0)

    @model_validator(mode="after")
    def _check(self):
        if NZ + self.kappa <= 0:
            raise ValueError(f"kappa: n + kappa must be > 0 (n = {NZ}, got kappa {self.kappa:g})")
        if any(f > self.process_noise_max for f in self.process_noise_floor):
            raise ValueError("process_noise_floor: must not exceed process_noise_max")
        return self


class _BatchedUKF(UnscentedKalmanFilter):
    """filterpy's UKF with the process function applied to all sigma points at once."""

    def compute_process_sigmas(self, dt, fx=None, **fx_args):
        fx = self.fx if fx is None else fx
        self.sigmas_f = np.asarray(fx(self.points_fn.sigma_points(self.x, self.P), dt, **fx_args), dtype=float)


def make_pd(P: np.ndarray, jitter_rel: float = 1e-9) -> tuple[np.ndarray, bool]:
    """Symmetrise ``P`` and add growing jitter ``eps * I`` until a Cholesky factorisation succeeds.

    Parameters
    ----------
    P : ndarray (n, n)
        Covariance.
    jitter_rel : float
        First eps, relative to the mean variance (tenfold per failure).

    Returns
    -------
    (ndarray, bool)
        The repaired covariance and whether jitter was needed.
    """
    P = 0.5 * (P + P.T)
    scale = max(float(np.mean(np.abs(np.diag(P)))), 1e-12)
    eps = jitter_rel * scale
    repaired = False
    for _ in range(40):
        try:
            np.linalg.cholesky(P)
            return P, repaired
        except np.linalg.LinAlgError:
            P = P + eps * np.eye(P.shape[0])
            eps *= 10.0
            repaired = True
    raise np.linalg.LinAlgError("covariance could not be repaired by jitter")


class UKFEstimator:
    """Unscented Kalman filter on a moment model (same API as :class:`ParticleFilter`).

    Parameters
    ----------
    model : MomentModel
        Needs ``x0()``, ``p0()``, ``state_names``, ``param_names`` and a vectorised
        ``step(X, u, dt_h, P)``.
    rng : numpy.random.Generator, optional
        Accepted for a common constructor; the UKF draws nothing.
    settings : UKFSettings, optional
    x0 : array, optional
        Initial moment state (default ``model.x0()``); one state, finite, hardening in [0, 1] and
        temperature >= -273.15 °C (else :class:`bmctl.errors.InputError`; not numbers: ``TypeError``).

    Examples
    --------
    >>> import numpy as np
    >>> from bmctl.moments import make_moment_model
    >>> ukf = UKFEstimator(make_moment_model("models/alni-1to1-300rpm-lab.toml"))
    >>> ukf.predict((300.0, 1.0), 1.0)
    >>> rng = np.random.default_rng(1)
    >>> est = ukf.update(rng.lognormal(np.log(45.0), 0.3, 300), rng.uniform(0.0, 0.1, 300), temperature_c=31.0)
    >>> est.t_h
    1.0
    """

    def __init__(self, model, rng: np.random.Generator | None = None, settings: UKFSettings | None = None, x0=None):
        self.model = model
        self.rng = rng
        self.settings = settings or UKFSettings()
        st = self.settings
        x0 = np.asarray(model.x0(), dtype=float) if x0 is None else check_x0(model, x0)
        p0 = np.asarray(model.p0(), dtype=float)
        if x0.size != 6 or p0.size != 2:
            raise ValueError("the UKF expects a 6-state, 2-parameter moment model")
        self.state_names = tuple(model.state_names)
        self.param_names = tuple(getattr(model, "param_names", ("gamma_mult", "delta_mult")))
        z = self._to_z(np.concatenate([x0, p0])[None, :])[0]
        P = np.diag(np.concatenate([np.full(N_MOMENTS, st.initial_spread**2), [st.initial_temperature_std_c**2],
                                    [st.hardening_noise_per_sqrt_h**2], np.full(2, st.param_prior_log_std**2)]))
        self.t_h = 0.0
        self.pending_h = 0.0  # hours of discrepancy noise not yet added (added at the next update)
        self.q = np.array(st.process_noise_per_sqrt_h, dtype=float)
        self.n_repaired = 0
        self.n_resampled = 0  # API parity with the particle filter (never resamples)
        self.last_fit = None
        self._ukf = self._new_ukf(z, P)

    # --- filterpy object -----------------------------------------------------------------
    def _new_ukf(self, z: np.ndarray, P: np.ndarray) -> _BatchedUKF:
        st = self.settings
        points = MerweScaledSigmaPoints(NZ, alpha=st.alpha, beta=st.beta, kappa=st.kappa)
        ukf = _BatchedUKF(dim_x=NZ, dim_z=N_MOMENTS, dt=1.0, hx=_h_moments, fx=self._fx, points=points)
        ukf.x = np.asarray(z, dtype=float).copy()
        ukf.P = np.asarray(P, dtype=float).copy()
        return ukf

    def __getstate__(self):  # pickling (trial checkpoints): filterpy's object holds bound methods
        d = dict(self.__dict__)
        ukf = d.pop("_ukf")
        d["_zP"] = (ukf.x.copy(), ukf.P.copy())
        return d

    def __setstate__(self, d):
        z, P = d.pop("_zP")
        self.__dict__.update(d)
        self._ukf = self._new_ukf(z, P)

    # --- coordinates -----------------------------------------------------------------------
    def _to_z(self, V: np.ndarray) -> np.ndarray:
        """(M, 8) states + multipliers -> filter coordinates (feasible)."""
        V = self._project(V.copy())
        Z = V.copy()
        Z[:, LOG_IDX] = np.log(V[:, LOG_IDX])
        return Z

    def _to_v(self, Z: np.ndarray) -> np.ndarray:
        """(M, 8) filter coordinates -> states + multipliers (feasible)."""
        V = np.array(Z, dtype=float, copy=True)
        lim = self.settings.log_mult_max
        V[:, 6:8] = np.clip(V[:, 6:8], -lim, lim)
        V[:, LOG_IDX] = np.exp(np.clip(V[:, LOG_IDX], -700.0, 700.0))
        return self._project(V)

    @staticmethod
    def _project(V: np.ndarray) -> np.ndarray:
        V[:, :6] = ParticleFilter._feasible(V[:, :6])
        V[:, 5] = np.clip(V[:, 5], 0.0, 1.0)
        return V

    def _fx(self, Z: np.ndarray, dt: float, u=None) -> np.ndarray:
        """All sigma points through the moment model over ``dt`` hours."""
        V = self._to_v(np.atleast_2d(Z))
        X = np.asarray(model_step(self.model, V[:, :6], np.asarray(u, dtype=float), dt, V[:, 6:8]), dtype=float)
        bad = ~np.all(np.isfinite(X), axis=1)
        if np.any(bad):
            X[bad] = V[bad, :6]
        return self._to_z(np.hstack([X, V[:, 6:8]]))

    def _repair(self) -> None:
        ukf = self._ukf
        ukf.P, repaired = make_pd(ukf.P, self.settings.jitter_rel)
        self.n_repaired += int(repaired)
        z = ukf.x.copy()
        ukf.x = self._to_z(self._to_v(z[None, :]))[0]  # mean back into the bounds

    # --- basics ----------------------------------------------------------------------------
    @property
    def names(self) -> tuple[str, ...]:
        return self.state_names + self.param_names

    @property
    def z(self) -> np.ndarray:
        """Filter-state mean (8,) in filter coordinates (copy)."""
        return self._ukf.x.copy()

    @property
    def cov(self) -> np.ndarray:
        """Filter-state covariance (8, 8) (copy; pending discrepancy noise not included)."""
        return self._ukf.P.copy()

    # --- predict / update ------------------------------------------------------------------
    def predict(self, u, dt_h: float) -> None:
        """Propagate mean and covariance over ``dt_h`` hours under ``u = (rpm, milling)``.

        Parameters
        ----------
        u : array_like, (2,)
            (rpm, milling).
        dt_h : float
            Interval (h); 0 does nothing, a negative or non-finite one is refused.
        """
        if check_predict(u, dt_h, getattr(self.model, "rpm_max", None)) <= 0:
            return
        st = self.settings
        q = np.zeros(NZ)
        q[4] = st.temperature_noise_c_per_sqrt_h**2
        q[5] = st.hardening_noise_per_sqrt_h**2
        q[6:8] = st.param_walk_per_sqrt_h**2
        self._ukf.Q = np.diag(q * dt_h)
        self._ukf.P, rep = make_pd(self._ukf.P, st.jitter_rel)
        self.n_repaired += int(rep)
        self._ukf.predict(dt=dt_h, u=np.asarray(u, dtype=float))
        self._repair()
        self.t_h += dt_h
        self.pending_h += dt_h

    def _adapt(self, fit, eta: np.ndarray, tau: float) -> None:
        """Innovation-based update of the discrepancy noise (the particle filter's rule)."""
        st = self.settings
        ukf = self._ukf
        var_m = np.diag(ukf.P)[:N_MOMENTS]
        meas_var = np.full(N_MOMENTS, np.inf)
        for b in range(2):
            sl = slice(2 * b, 2 * b + 2)
            if fit.ok[b] and eta[b] > 0:
                meas_var[sl] = np.diag(np.linalg.inv(eta[b] * fit.info[sl, sl]))
        innov2 = (fit.z - ukf.x[:N_MOMENTS]) ** 2
        ok = np.repeat(fit.ok, 2) & np.isfinite(meas_var)
        q2_new = np.maximum(innov2 - var_m - meas_var, 0.0) / tau
        q2 = (1 - st.adapt_rate) * self.q**2 + st.adapt_rate * q2_new
        q = np.clip(np.sqrt(q2), np.asarray(st.process_noise_floor, dtype=float), st.process_noise_max)
        self.q = np.where(ok, q, self.q)

    def update(self, s_um=None, r=None, temperature_c: float | None = None) -> Estimate:
        """Condition on a micrograph sample and/or a temperature reading.

        Parameters
        ----------
        s_um, r : array_like, optional
            Measured sizes (um, > 0) and aspect ratios ([0, 1)) of one sample.
        temperature_c : float, optional
            Vial-temperature reading.

        Returns
        -------
        Estimate
            ``ess`` is NaN (no particles); ``eta`` and ``n_measured`` as the particle filter's.

        Raises
        ------
        bmctl.errors.InputError
            As :meth:`bmctl.estimate.ParticleFilter.update` (:func:`bmctl.estimate.filter.check_update`);
            nothing is changed then.
        """
        st = self.settings
        reading, raster = check_update(self.model, s_um, r, temperature_c, st.law)
        ukf = self._ukf
        tau = self.pending_h
        eta = np.array([np.nan, np.nan])
        n_meas = 0
        rows: list[int] = []
        y: list[float] = []
        R_blocks: list[np.ndarray] = []
        fit = None
        if raster is not None:
            n_meas = raster.n
            fit = fit_sample(raster, st.law)
            self.last_fit = fit
            eta = learning_rates(fit, st)
            if st.adapt and tau > 0:
                self._adapt(fit, eta, tau)
        # the deferred discrepancy noise of the log moments (Eq.: z_k = f(z_{k-1}) + w, w ~ N(0, q^2 tau))
        if tau > 0:
            ukf.P[:N_MOMENTS, :N_MOMENTS] += np.diag(self.q**2 * tau)
        if fit is not None:
            for b in range(2):
                sl = slice(2 * b, 2 * b + 2)
                if fit.ok[b] and eta[b] > 0:
                    rows += [2 * b, 2 * b + 1]
                    y += list(fit.z[sl])
                    R_blocks.append(np.linalg.inv(eta[b] * fit.info[sl, sl]))
        R = np.zeros((len(rows) + 1, len(rows) + 1))
        k = 0
        for blk in R_blocks:
            R[k:k + 2, k:k + 2] = blk
            k += 2
        if reading is not None:
            rows.append(4)
            y.append(reading)
            R[k, k] = st.sigma_temperature_c**2
            k += 1
        R = R[:k, :k]
        self._ukf.P, rep = make_pd(ukf.P, st.jitter_rel)
        self.n_repaired += int(rep)
        if rows:
            ukf.sigmas_f = ukf.points_fn.sigma_points(ukf.x, ukf.P)  # sigma points of the current prior
            idx = np.array(rows)
            ukf.update(np.array(y), R=0.5 * (R + R.T), hx=lambda s: s[idx])
            self._repair()
        self.pending_h = 0.0
        est = self.estimate()
        est.eta, est.n_measured = tuple(float(e) for e in eta), n_meas
        return est

    # --- read-out --------------------------------------------------------------------------
    def estimate(self) -> Estimate:
        """Mean and 90 % interval of every state and parameter (pending discrepancy noise included)."""
        ukf = self._ukf
        m = ukf.x.copy()
        var = np.clip(np.diag(ukf.P).copy(), 0.0, None)
        var[:N_MOMENTS] += self.q**2 * self.pending_h
        sd = np.sqrt(var)
        mean, lo, hi = m.copy(), m - Z90 * sd, m + Z90 * sd
        mean[LOG_IDX] = np.exp(m[LOG_IDX] + 0.5 * var[LOG_IDX])
        lo[LOG_IDX], hi[LOG_IDX] = np.exp(lo[LOG_IDX]), np.exp(hi[LOG_IDX])
        # a log-normal mean can leave the state bounds (r_mean < 0.9 ...) when the variance is large
        self._project(mean[None, :])  # in place on the states
        return Estimate(self.t_h, self.names, mean, lo, hi, float("nan"))

    # --- state round trip ------------------------------------------------------------------
    def get_state(self) -> dict:
        """Plain-data state (arrays and numbers): enough to continue identically.

        Returns
        -------
        dict
            ``z`` (8,), ``P`` (8, 8), ``q`` (4,), ``t_h``, ``pending_h``, ``n_repaired``.
        """
        return {"z": self._ukf.x.copy(), "P": self._ukf.P.copy(), "q": self.q.copy(), "t_h": float(self.t_h),
                "pending_h": float(self.pending_h), "n_repaired": int(self.n_repaired)}

    def set_state(self, state: dict) -> None:
        """Restore a state from :meth:`get_state` (validated: shapes, finiteness).

        Parameters
        ----------
        state : dict
            As returned by :meth:`get_state`.
        """
        try:
            z = np.asarray(state["z"], dtype=float).reshape(NZ)
            P = np.asarray(state["P"], dtype=float).reshape(NZ, NZ)
            q = np.asarray(state["q"], dtype=float).reshape(N_MOMENTS)
            t_h, pending_h = float(state["t_h"]), float(state["pending_h"])
            n_rep = int(state.get("n_repaired", 0))
        except (KeyError, ValueError, TypeError) as exc:
            raise ValueError(f"UKF state: {exc}") from None
        if not (np.all(np.isfinite(z)) and np.all(np.isfinite(P)) and np.all(q > 0) and pending_h >= 0):
            raise ValueError("UKF state: z, P must be finite, q > 0 and pending_h >= 0")
        self._ukf = self._new_ukf(z, P)
        self.q, self.t_h, self.pending_h, self.n_repaired = q, t_h, pending_h, n_rep


def _h_moments(z: np.ndarray) -> np.ndarray:
    """Default measurement function: the log moments."""
    return np.asarray(z)[:N_MOMENTS]
