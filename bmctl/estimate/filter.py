"""A particle filter over the moment-model state and uncertain rate parameters.

The model is one small object (the moment model: ``step``, ``x0``, ``p0``, ``state_names``);
the algorithm lives here, apart (as in Chopin's ``particles``). Each particle carries the
moment state x = (s_mean_um, s_std_um, r_mean, r_std, temperature_c, hardening) and the log
of the parameter multipliers (gamma_mult, delta_mult).

Propagation
    the moment model under the applied (rpm, milling), then model-discrepancy noise: a
    random walk in z = ln(s_mean, s_std, r_mean, r_std) of std ``q * sqrt(tau)`` (tau: hours
    since the noise was last applied) and a random walk of the vial's heating gain. The noise
    is applied lazily, once per update (or when an estimate is read), so that the update can
    draw it from a guided proposal. The parameters take a small random walk.
Vial temperature
    the card's thermal law (eqn 7: T relaxes to ambient + P tau_c / C within about an hour) is
    only as good as its heat capacity and cooling time, and it forgets a corrected
    temperature within an interval. Each particle therefore carries a heating gain g: its vial
    runs at T = T_amb + g (T_law - T_amb), where T_law follows the card's law (the model steps
    T_amb + (T - T_amb) / g, and the result is scaled back: exact for the linear law, and a
    rest still cools to ambient). g = 1 until the first reading, at which its prior
    N(1, ``thermal_gain_prior_std``^2) is weighed in; afterwards it walks
    (``thermal_gain_walk_per_sqrt_h``) and, with probability ``thermal_gain_jump_prob`` at a
    reading, jumps by a draw from its prior (a changed vial or cooling), so a reading far from
    the estimate is followed rather than ignored.
Update
    the likelihood of a micrograph sample (:func:`likelihood.loglik_raster`: the measured
    particles under the laws the state implies, through a measurement-noise model), raised
    to a learning rate (power likelihood), and optionally a vial-temperature reading
    (Gaussian, std ``sigma_temperature_c``); the reading is linear in g, so the gain's change
    is drawn from its exact posterior (a two-component Gaussian mixture: walk or jump).
Proposal
    for every particle, the Gaussian product of its discrepancy prior N(m_i, Q) with a
    Gaussian approximation N(z_hat, (eta I)^-1) of the (tempered) likelihood, mixed with the
    prior itself (defensive importance sampling, weight ``defensive``); the weights carry
    the exact likelihood and densities, so the target is unchanged (Doucet, Godsill &
    Andrieu 2000). This keeps the filter alive when n measured particles make the
    likelihood far narrower than the model's one-step error.
Resampling
    when ESS < ``ess_fraction`` N (``bmctl.estimate.resampling``, drawn from the filter's generator), then roughening of the log
    parameters (Gordon, Salmond & Smith 1993).

Misspecification (docs/estimation.md): the plant's particles do not follow the implied laws
exactly and the moment model is not exact between samples. The filter handles this
explicitly with (1) the measurement-noise model (r noise and the r = 0 floor), (2) a power
likelihood whose learning rate is the per-sample calibration of Lyddon, Holmes & Walker
(2019) capped by ``learning_rate`` (Holmes & Walker 2017 power likelihood), and (3) process
noise sized to the model's one-step error, optionally adapted online from the innovations
(``adapt``, Mehra 1972).

Multi-rate by construction: call ``predict`` every control interval and ``update`` only when
a sample (or reading) arrives.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, field_validator

from ..config import Range, Strict
from ..errors import InputError, require_generator
from ..moments.model import ENERGY_NAME, MomentModel
from ..limits import INPUT_ROUNDING, RPM_MAX, is_rpm_milling, rpm_rounding
from .likelihood import LOG_P_FLOOR, LawSettings, Raster, fit_sample, loglik_raster
from .resampling import SCHEMES, effective_sample_size, resample

N_MOMENTS = 4  # s_mean, s_std, r_mean, r_std: the log-moment block z
N_PARTICLES_MIN = 10  # the fewest filter particles
#: the lowest vial-temperature reading accepted (C)
READING_MIN_C = -50.0
GAIN_MIN = 0.05  # the smallest vial heating gain over the card's thermal law
FEED_VAR_FLOOR = 1e-10  # the variance of a log moment the feed's sample does not fit (its prior is the card's)


#: a log moment's noise per sqrt(hour): > 0 and finite (10: a factor e^10 an hour, far past any use)
_Noise = Range(0.0, 10.0, lo_open=True)
_NoiseFloor = Range(0.0, 10.0)


class FilterSettings(Strict):
    """Particle-filter settings (all dimensionless unless suffixed); a scenario's ``[estimator]`` table.

    Attributes
    ----------
    n_particles : int
        Number of filter particles N.
    ess_fraction : float
        Resample when ESS < ess_fraction * N.
    scheme : str
        Resampling scheme (``bmctl.estimate.resampling``): systematic, stratified, residual, multinomial.
    process_noise_per_sqrt_h : tuple of 4 floats
        Model-discrepancy random walk of ln(s_mean, s_std, r_mean, r_std) per sqrt(hour).
        Defaults from the moment model's one-step (1 h) errors against the plant
        (docs/estimation.md): the r moments relax to the model's own level within an hour.
    adapt : bool
        Adapt the process noise from the innovations (sample fit minus prediction).
    adapt_rate : float
        Forgetting factor of the adaptation (share of the newest innovation).
    process_noise_floor : tuple of 4 floats
        Lower limits of the adapted per-sqrt(hour) noise of each log moment.
    process_noise_max : float
        Upper limit of the adapted per-sqrt(hour) noise.
    size_drift_prior_per_h : float
        Offset-free size estimate: each particle carries a drift rate b of ln(s_mean) (and
        ln(s_std), the size law's spread kept) per milling hour that the moment model misses
        (a powder mass or ball count its gamma, delta cannot describe); this is b's prior std
        (1/h). 0: no drift (the default).
    size_drift_walk_per_sqrt_h : float
        Random walk of b per sqrt(milling hour) (its operating point moves).
    rest_noise_fraction : float
        Share of a rest hour that counts as model-discrepancy time for the moment noise (the
        powder does not change at rest; the vial's gain walks on wall hours regardless).
        1: wall hours (the default). Small (a campaign's 0.02): hourly samples of a resting
        mill average out instead of each one moving the estimate; 0 leaves the cloud of a long
        rest no jitter at all, and reweighting alone degenerates it (docs/estimation.md, "Rests").
    moment_noise_at : {"update", "sample"}
        When the moments' deferred discrepancy noise is drawn. "update" (the default): at every
        update, a temperature reading alone included, where nothing guides it (drawn from its
        prior); "sample": only at a micrograph sample, whose guided proposal draws it, so a
        reading between samples leaves it deferred (estimates read in between show it)
        (docs/estimation.md, "Readings between samples").
    thermal_gain_prior_std : float
        Prior std of the vial's heating gain g over the card's thermal law (1: the card is exact),
        weighed in at the first reading.
    thermal_gain_walk_per_sqrt_h : float
        Random walk of g per sqrt(hour).
    thermal_gain_jump_prob : float
        Prior probability, at each later reading, that g changed by a draw from its prior.
    param_prior_log_std : float
        Std of the initial log multipliers (0.4 ~ +-40 %).
    energy_prior_log_std : float
        > 0: every particle carries a third multiplier, ``energy_mult``, of the impact energy per
        particle against the card's (a ball size, ball count or powder mass the card does not
        have; docs/estimation.md), with this prior std of its log. 0: (gamma_mult, delta_mult) only.
    param_walk_per_sqrt_h : float
        Random walk of the log multipliers per sqrt(hour).
    roughening : float
        Roughening constant K of Gordon et al. (jitter std = K * range * N^(-1/d)).
    initial_spread : float
        Relative spread of the initial moment states.
    feed_log_std : float
        Prior std of the log moments of the feed powder beyond ``initial_spread``, spent on the
        first sample when it is taken before any milling (a sample of the feed): a feed that
        differs from the card's ``[initial]`` is read off its sample instead of collapsing the
        filter onto the particle nearest to it (docs/estimation.md, "The feed"). Blocks (size,
        shape) the sample does not fit keep the card's. 0: the card's starting powder is held.
    learning_rate : float
        Cap on the power-likelihood learning rate eta (1: the per-sample calibration alone).
    calibrate_learning_rate : bool
        Use the per-sample Lyddon-Holmes-Walker rate (else eta = learning_rate).
    defensive : float
        Share of the proposal drawn from the prior (bootstrap) rather than the guided density.
    proposal : {"guided", "bootstrap"}
        "bootstrap" draws the process noise from its prior only (the plain bootstrap filter,
        kept for comparison: it collapses when n is large, docs/estimation.md).
    law : LawSettings
        Measurement laws (size law, noise) and raster.
    sigma_temperature_c : float
        Noise (std) of a vial-temperature reading (degC).
    """

    n_particles: Annotated[int, Field(ge=N_PARTICLES_MIN)] = 2000
    ess_fraction: Annotated[float, Field(gt=0, le=1)] = 0.5
    scheme: str = "systematic"
    process_noise_per_sqrt_h: tuple[_Noise, _Noise, _Noise, _Noise] = (0.15, 0.15, 0.8, 0.8)
    adapt: bool = True
    adapt_rate: Range(0.0, 1.0, lo_open=True) = 0.3
    process_noise_floor: tuple[_NoiseFloor, _NoiseFloor, _NoiseFloor, _NoiseFloor] = (0.05, 0.08, 0.2, 0.2)
    process_noise_max: _Noise = 1.5
    size_drift_prior_per_h: Annotated[float, Field(ge=0, le=1)] = 0.0
    size_drift_walk_per_sqrt_h: Annotated[float, Field(ge=0, le=1)] = 0.0
    rest_noise_fraction: Annotated[float, Field(ge=0, le=1)] = 1.0
    moment_noise_at: Literal["update", "sample"] = "update"
    thermal_gain_prior_std: Annotated[float, Field(ge=0, le=2)] = 0.3
    thermal_gain_walk_per_sqrt_h: Annotated[float, Field(ge=0, le=1)] = 0.05
    thermal_gain_jump_prob: Annotated[float, Field(ge=0, lt=1)] = 0.02
    param_prior_log_std: Range(0.0, 3.0) = 0.4
    energy_prior_log_std: Annotated[float, Field(ge=0, le=2)] = 0.0
    param_walk_per_sqrt_h: Range(0.0, 1.0) = 0.01
    roughening: Range(0.0, 1.0) = 0.05
    initial_spread: Range(0.0, 1.0) = 0.02
    feed_log_std: Annotated[float, Field(ge=0, le=3)] = 1.0
    learning_rate: Annotated[float, Field(gt=0, le=1)] = 1.0
    calibrate_learning_rate: bool = True
    defensive: Annotated[float, Field(ge=0, lt=1)] = 0.1
    proposal: Literal["guided", "bootstrap"] = "guided"
    law: LawSettings = Field(default_factory=LawSettings)
    sigma_temperature_c: Range(0.0, 100.0, lo_open=True) = 2.0

    @field_validator("scheme")
    @classmethod
    def _known_scheme(cls, v: str) -> str:
        if v not in SCHEMES:
            raise ValueError(f"must be one of {SCHEMES}")
        return v

    @field_validator("process_noise_per_sqrt_h")
    @classmethod
    def _positive_noise(cls, v: tuple) -> tuple:
        if min(v) <= 0:
            raise ValueError("four values > 0")
        return v

    def replace(self, **changes) -> "FilterSettings":
        """A validated copy with ``changes`` (``law`` may be a LawSettings or a dict of its fields)."""
        return type(self).model_validate({**self.model_dump(exclude={"law"}), "law": self.law, **changes})


@dataclass
class Estimate:
    """Weighted summary of the filter at one time.

    Attributes
    ----------
    t_h : float
        Time (h).
    names : tuple of str
        State then parameter names (the columns of mean, q05, q95).
    mean, q05, q95 : ndarray
        Weighted mean and 5 % / 95 % quantiles of every state and parameter.
    ess : float
        Effective sample size after the update (before any resampling).
    resampled : bool
        Whether the update resampled.
    degenerate : bool
        Whether every particle was impossible (prior weights kept).
    eta : tuple of 2 floats
        Learning rates of the size and shape blocks (NaN without a sample).
    n_measured : int
        Measured particles in the sample (0 without one).
    extra : dict
        Further read-outs, name -> (weighted mean, q05, q95): the particle filter's
        ``thermal_gain`` (the vial's heating over the card's thermal law).
    size_stats : dict
        Volume-weighted ``d10_um, d50_um, d90_um, span`` and area-weighted ``s_mean_area_um,
        s_mode_area_um`` of the particles' size laws (closed form of each particle's mean and
        std, :func:`bmctl.stats.law_size_stats`, as the moment model's ``outputs``): name ->
        (weighted mean, q05, q95) over the filter's particles.
    """

    t_h: float
    names: tuple[str, ...]
    mean: np.ndarray
    q05: np.ndarray
    q95: np.ndarray
    ess: float
    resampled: bool = False
    degenerate: bool = False
    eta: tuple = (float("nan"), float("nan"))
    n_measured: int = 0
    size_stats: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)

    def as_dict(self) -> dict[str, float]:
        """Flat dict: t_h, ess, and <name>, <name>_q05, <name>_q95 for every state, parameter,
        size statistic and extra read-out."""
        d = {"t_h": self.t_h, "ess": self.ess}
        for k, n in enumerate(self.names):
            d[n] = float(self.mean[k])
            d[f"{n}_q05"] = float(self.q05[k])
            d[f"{n}_q95"] = float(self.q95[k])
        for n, (m, lo, hi) in {**self.size_stats, **self.extra}.items():
            d[n], d[f"{n}_q05"], d[f"{n}_q95"] = float(m), float(lo), float(hi)
        return d

    def interval(self, name: str) -> tuple[float, float]:
        k = self.names.index(name)
        return float(self.q05[k]), float(self.q95[k])


def particle_size_stats(model, X: np.ndarray, weights: np.ndarray) -> dict:
    """Weighted mean and 90 % interval over particles of each size statistic of their laws.

    The statistics are the moment model's closed forms (``model.outputs``: volume-weighted
    D-values and span, area-weighted mean and mode); a model without them falls back to
    :func:`bmctl.stats.law_size_stats` of columns 0 and 1 (the same function).
    Returns name -> (mean, q05, q95).
    """
    from ..stats import SIZE_STAT_NAMES, law_size_stats

    out = model.outputs(X) if hasattr(model, "outputs") else {}
    if not all(k in out for k in SIZE_STAT_NAMES):
        out = law_size_stats(X[:, 0], X[:, 1])
    V = np.column_stack([np.broadcast_to(out[k], X.shape[:1]) for k in SIZE_STAT_NAMES])
    q = weighted_quantiles(V, weights)
    mean = (weights / weights.sum()) @ V
    return {k: (float(mean[j]), float(q[0, j]), float(q[1, j])) for j, k in enumerate(SIZE_STAT_NAMES)}


def weighted_quantiles(values: np.ndarray, weights: np.ndarray, qs=(0.05, 0.95)) -> np.ndarray:
    """Quantiles of each column of ``values`` (N, d) under ``weights`` (N,). Returns (len(qs), d)."""
    order = np.argsort(values, axis=0)
    w = weights / weights.sum()
    out = np.empty((len(qs), values.shape[1]))
    for j in range(values.shape[1]):
        v = values[order[:, j], j]
        wj = w[order[:, j]]
        c = np.cumsum(wj) - 0.5 * wj
        out[:, j] = np.interp(qs, c, v)
    return out


def _logsumexp(a: np.ndarray) -> float:
    m = float(np.max(a))
    return m + math.log(float(np.sum(np.exp(a - m))))


def check_predict(u, dt_h, rpm_max: float | None = None) -> float:
    """Refuse an estimator's ``predict`` input that is not (rpm in [0, ``rpm_max``], milling in [0, 1])
    for a finite ``dt_h`` >= 0 hours, naming the argument; returns ``dt_h`` as a float (0 for a ``dt_h``
    within :data:`INPUT_ROUNDING` below 0). Each bound allows a solver's rounding (:data:`INPUT_ROUNDING`;
    for the top speed :func:`bmctl.limits.rpm_rounding`).

    Parameters
    ----------
    u : array_like, (2,)
        (rpm, milling).
    dt_h : float
        Interval (h).
    rpm_max : float, optional
        The model's top speed (default :data:`bmctl.limits.RPM_MAX`, the kinematics' ceiling).
    """
    try:
        dt = float(dt_h)
    except (TypeError, ValueError):
        raise InputError(f"dt_h: must be a number of hours (got {dt_h!r})") from None
    if not (math.isfinite(dt) and dt >= -INPUT_ROUNDING):
        raise InputError(f"dt_h: must be a finite number of hours >= 0 (got {dt_h!r})")
    if not is_rpm_milling(u):
        raise InputError(f"u: must be (rpm, milling), finite, rpm >= 0 and milling in [0, 1] (got {u!r})")
    top = RPM_MAX if rpm_max is None else float(rpm_max)
    if float(u[0]) > top + rpm_rounding(top):
        raise InputError(f"u: rpm {float(u[0]):g} exceeds the model's rpm_max {top:g} (got {u!r})")
    return max(dt, 0.0)


def check_x0(model, x0) -> np.ndarray:
    """An estimator's given initial state as a float array of shape ``(len(model.state_names),)``,
    refusing (naming ``x0``) a wrong shape, a value that is not finite and, for the moment model,
    hardening outside [0, 1] or a temperature below absolute zero (as the model's own checks).

    Raises
    ------
    TypeError
        ``x0`` not an array of numbers.
    bmctl.errors.InputError
        ``x0`` of another shape or with a value out of range.
    """
    names = tuple(model.state_names)
    try:
        x = np.asarray(x0, dtype=float)
    except (TypeError, ValueError):
        raise TypeError(f"x0: must be an array of numbers, one state {names} (got {type(x0).__name__})") from None
    if x.shape != (len(names),):
        raise InputError(f"x0: must be one state {names} of shape ({len(names)},) (got shape {x.shape})")
    if isinstance(model, MomentModel):
        model._check_values(x, "x0")
    elif not all(map(math.isfinite, x.tolist())):
        k = int(np.argmax(~np.isfinite(x)))
        raise InputError(f"x0: {names[k]} must be finite (got {float(x[k]):g})")
    return x


def model_step(model, X: np.ndarray, u: np.ndarray, dt_h: float, P: np.ndarray) -> np.ndarray:
    """One step of a filter's particles (or sigma points): ``model.step(X, u, dt_h, P)``, for a
    :class:`MomentModel` without the argument checks of its public entry (the estimator checked ``u`` and
    ``dt_h``; its own states and multipliers are what it made them, and a failed step, non-finite, is
    kept where it was rather than refused), the same numbers."""
    if isinstance(model, MomentModel):
        return model._step(X, u, dt_h, P)
    return model.step(X, u, dt_h, P)


def check_reading(card, temperature_c: float | None, where: str) -> float | None:
    """Refuse a vial-temperature reading outside [READING_MIN_C, the card's melting limit].

    Parameters
    ----------
    card : ModelCard or None
        The card whose powder's melting point caps a reading (None: no card, then the highest
        melting point of any powder bmctl models, :data:`bmctl.cards.TEMPERATURE_CEILING_C`).
    temperature_c : float or None
        The reading (None: no reading).
    where : str
        The flag or file named in the message.
    """
    if temperature_c is None:
        return None
    hi, reason = _reading_limit(card)
    if not (math.isfinite(temperature_c) and READING_MIN_C <= temperature_c <= hi):
        raise InputError(f"{where}: reading {temperature_c:g} °C outside [{READING_MIN_C:g}, {hi:g}] °C "
                         f"(-50 °C to {reason})")
    return temperature_c


def check_update(model, s_um, r, temperature_c,
                 law: LawSettings | None = None) -> tuple[float | None, Raster | None]:
    """What an estimator's ``update`` refuses, before anything changes: the checks of ``run_filter``
    (:func:`bmctl.estimate.run.check_sample` and :func:`check_reading`); returns the reading as a float
    and the sample counted on the raster of ``law`` (:meth:`Raster.from_particles`, which checks the
    particles), each None where not given.

    Parameters
    ----------
    model : MomentModel
        The estimator's model (its ``card`` caps a reading).
    s_um, r : array_like or None
        Measured sizes (um) and aspect ratios of one sample (``s_um`` None: no sample).
    temperature_c : float or None
        Vial-temperature reading (degC).
    law : LawSettings, optional
        The raster the sample is counted on (default ``LawSettings()``).

    Raises
    ------
    bmctl.errors.InputError
        No particles, s_um or r alone, unequal numbers of s and r, a size outside 1e-3 .. 1e4 um, r outside [0, 1),
        a reading that is not finite or outside [-50 degC, the card's melting limit].
    TypeError
        A sample or reading that is not numbers.
    """
    raster = None
    if (s_um is None) != (r is None):  # r alone was ignored: an update without the sample it was given
        raise InputError("s_um, r: a sample needs one or more particles with one s and one r each (got "
                         f"{'r' if s_um is None else 's_um'} only)")
    if s_um is not None:
        try:
            s = np.asarray(s_um, dtype=float).ravel()
            rr = np.asarray(r, dtype=float).ravel()
        except (TypeError, ValueError):
            raise TypeError(f"s_um, r: a sample is two arrays of numbers (got {type(s_um).__name__} and "
                            f"{type(r).__name__})") from None
        raster = Raster.from_particles(s, rr, law)  # checks the particles (check_particles)
    if temperature_c is None:
        return None, raster
    if isinstance(temperature_c, (bool, str, bytes)):
        raise TypeError(f"temperature_c: a reading is a number of degC (got {type(temperature_c).__name__})")
    try:
        t = float(temperature_c)
    except (TypeError, ValueError):
        raise TypeError(f"temperature_c: a reading is a number of degC (got {type(temperature_c).__name__})") from None
    return check_reading(getattr(model, "card", None), t, "temperature_c"), raster


#: the (card, its powder, its validity) a reading was last checked against, and the limit
_READING_LIMIT: list = [None]


def _reading_limit(card) -> tuple[float, str]:
    """The highest reading accepted under ``card`` (None: no card) and the reason (:func:`check_reading`);
    kept for the last card (the powder's melting point costs ~20 us, an estimator's update checks it)."""
    key = (card, getattr(card, "powder", None), getattr(card, "validity", None))
    cached = _READING_LIMIT[0]
    if cached is not None and all(a is b for a, b in zip(cached[0], key)):
        return cached[1]
    from ..cards import TEMPERATURE_CEILING_C, melting_limit

    limit = (TEMPERATURE_CEILING_C, "the highest melting point of any powder bmctl models") if card is None \
        else melting_limit(card)
    _READING_LIMIT[0] = (key, limit)
    return limit


class ParticleFilter:
    """Particle filter on a moment model with guided, tempered updates.

    Parameters
    ----------
    model : MomentModel
        Needs ``x0()``, ``p0()``, ``state_names``, ``param_names`` (optional) and a vectorised
        ``step(X, u, dt_h, P)`` for X of shape (N, nx) and P of shape (N, np).
    rng : numpy.random.Generator
        The single source of randomness (resampling included).
    settings : FilterSettings or dict, optional
        The settings (a dict of its fields is validated as a scenario's ``[estimator.pf]``).
    x0 : array, optional
        Initial moment state (default ``model.x0()``); one state, finite, hardening in [0, 1] and
        temperature >= -273.15 °C (else :class:`bmctl.errors.InputError`; not numbers: ``TypeError``).

    Examples
    --------
    >>> import numpy as np
    >>> from bmctl.moments import make_moment_model
    >>> from bmctl.estimate.filter import FilterSettings, ParticleFilter
    >>> model = make_moment_model("models/alni-1to1-300rpm-lab.toml")
    >>> pf = ParticleFilter(model, np.random.default_rng(0), FilterSettings(n_particles=200))
    >>> pf.predict((300.0, 1.0), 1.0)
    >>> rng = np.random.default_rng(1)
    >>> est = pf.update(s_um=rng.lognormal(np.log(45.0), 0.3, 300), r=rng.uniform(0.0, 0.1, 300))
    >>> est.t_h, len(est.mean) == len(est.names)
    (1.0, True)
    """

    def __init__(self, model, rng: np.random.Generator, settings: FilterSettings | None = None, x0=None):
        require_generator(rng, "rng")
        if not (hasattr(model, "x0") and hasattr(model, "p0")):  # None gave an AttributeError further in
            raise TypeError(f"model: must be a moment model (bmctl.moments.make_moment_model), got "
                            f"{type(model).__name__}")
        if isinstance(settings, dict):  # a scenario's [estimator.pf] table as it reads
            settings = FilterSettings.model_validate(settings)
        elif settings is not None and not isinstance(settings, FilterSettings):
            raise TypeError(f"settings: must be a FilterSettings or a dict of its fields, got {type(settings).__name__}")
        self.model = model
        self.rng = rng
        self.settings = settings or FilterSettings()
        st = self.settings
        N = st.n_particles
        x0 = np.asarray(model.x0(), dtype=float) if x0 is None else check_x0(model, x0)
        p0 = np.asarray(model.p0(), dtype=float)
        prior = np.full(p0.size, st.param_prior_log_std)
        if st.energy_prior_log_std > 0:
            p0, prior = np.append(p0, 1.0), np.append(prior, st.energy_prior_log_std)
        self.nx, self.np_ = x0.size, p0.size
        X = np.tile(x0, (N, 1))
        X[:, :N_MOMENTS] *= np.exp(st.initial_spread * rng.standard_normal((N, N_MOMENTS)))
        self.X = self._feasible(X)
        self.logP = np.log(p0)[None, :] + prior[None, :] * rng.standard_normal((N, self.np_))
        self.logw = np.full(N, -np.log(N))
        self.t_h = 0.0
        self.pending_h = 0.0  # hours of process noise not yet applied (the vial's gain)
        self.pending_model_h = 0.0  # hours of moment discrepancy noise not yet applied (rest_noise_fraction)
        self.q = np.array(st.process_noise_per_sqrt_h, dtype=float)
        self.state_names = tuple(model.state_names)
        names = tuple(getattr(model, "param_names", ("gamma_mult", "delta_mult")))
        self.param_names = names + (ENERGY_NAME,) * (self.np_ - len(names))  # the appended energy_mult
        self.n_resampled = 0
        self.n_degenerate = 0
        self.last_fit = None
        self.ambient_c = float(np.asarray(model.x0(), dtype=float)[4])
        self.gain = np.ones(N)  # each particle's vial heating gain over the card's thermal law
        self.gain_var = st.thermal_gain_prior_std**2  # the gain's prior variance, spent on the first reading
        # each particle's drift of ln(s_mean, s_std) per milling hour over the moment model (1/h)
        self.drift = st.size_drift_prior_per_h * rng.standard_normal(N) if st.size_drift_prior_per_h > 0 \
            else np.zeros(N)
        self.feed_open = st.feed_log_std > 0  # the feed's prior not yet spent: no sample, no milling

    # --- state ------------------------------------------------------------------------------
    def get_state(self) -> dict:
        """The particles, weights, clocks, adapted noise and generator state as plain data."""
        return {"X": self.X.copy(), "logP": self.logP.copy(), "logw": self.logw.copy(), "t_h": self.t_h,
                "pending_h": self.pending_h, "pending_model_h": self.pending_model_h, "q": self.q.copy(),
                "n_resampled": self.n_resampled, "n_degenerate": self.n_degenerate, "rng": self.rng.bit_generator.state,
                "gain": self.gain.copy(), "gain_var": self.gain_var, "drift": self.drift.copy(),
                "feed_open": self.feed_open}

    def set_state(self, state: dict) -> None:
        """Restore a state from :meth:`get_state` (the settings and the model are the constructor's)."""
        self.X = np.array(state["X"], dtype=float)
        self.logP = np.array(state["logP"], dtype=float)
        self.logw = np.array(state["logw"], dtype=float)
        self.t_h = float(state["t_h"])
        self.pending_h = float(state["pending_h"])
        self.pending_model_h = float(state.get("pending_model_h", self.pending_h))
        self.q = np.array(state["q"], dtype=float)
        self.n_resampled = int(state["n_resampled"])
        self.n_degenerate = int(state["n_degenerate"])
        self.rng.bit_generator.state = state["rng"]
        # a state written before the gain existed: the card's law, its prior not yet spent
        self.gain = np.array(state["gain"], dtype=float) if "gain" in state else np.ones(self.X.shape[0])
        self.gain_var = float(state.get("gain_var", self.settings.thermal_gain_prior_std**2))
        self.drift = np.array(state["drift"], dtype=float) if "drift" in state else np.zeros(self.X.shape[0])
        self.feed_open = bool(state.get("feed_open", False))  # a state written before: the card's feed held

    # --- basics -----------------------------------------------------------------------------
    @property
    def names(self) -> tuple[str, ...]:
        return self.state_names + self.param_names

    @property
    def weights(self) -> np.ndarray:
        w = np.exp(self.logw - self.logw.max())
        return w / w.sum()

    @property
    def P(self) -> np.ndarray:
        """Parameter multipliers of every particle (N, np)."""
        return np.exp(self.logP)

    @staticmethod
    def _feasible(X: np.ndarray) -> np.ndarray:
        """Keep moment sets realisable: positive sizes, r in (0, 1), Beta-feasible r variance."""
        X[:, 0] = np.clip(X[:, 0], 0.1, 1e5)
        X[:, 1] = np.clip(X[:, 1], 1e-3 * X[:, 0], 30 * X[:, 0])
        X[:, 2] = np.clip(X[:, 2], 1e-4, 0.9)
        X[:, 3] = np.clip(X[:, 3], 1e-4, 0.99 * np.sqrt(X[:, 2] * (1 - X[:, 2])))
        return X

    # --- prediction -------------------------------------------------------------------------
    def predict(self, u, dt_h: float) -> None:
        """Propagate every particle over ``dt_h`` hours under input ``u = (rpm, milling)``.

        Parameters
        ----------
        u : array_like, (2,)
            (rpm, milling): sun-disc speed and the share of the interval spent milling.
        dt_h : float
            Interval (h); 0 does nothing, a negative or non-finite one is refused.
        """
        if check_predict(u, dt_h, getattr(self.model, "rpm_max", None)) <= 0:
            return
        st, rng = self.settings, self.rng
        X_law = self.X.copy()
        X_law[:, 4] = self.ambient_c + self._excess()  # the card's thermal law runs on T_amb + (T - T_amb) / g
        X = np.asarray(model_step(self.model, X_law, np.asarray(u, dtype=float), dt_h, self.P), dtype=float)
        X[:, 4] = self.ambient_c + self.gain * (X[:, 4] - self.ambient_c)
        bad = ~np.all(np.isfinite(X), axis=1)
        if np.any(bad):  # a failed model step keeps the particle where it was (and reports nothing)
            X[bad] = self.X[bad]
        mill_h = dt_h * float(np.clip(u[1], 0.0, 1.0)) if float(u[0]) > 0 else 0.0
        if mill_h > 0:
            self.feed_open = False  # the powder has changed: the feed is no longer what a sample reads
        if st.size_drift_prior_per_h > 0 and mill_h > 0:  # the model's missed size drift while milling
            f = np.exp(self.drift * mill_h)
            X[:, 0] *= f
            X[:, 1] *= f
            walk = st.size_drift_walk_per_sqrt_h * math.sqrt(mill_h)
            self.drift = self.drift + walk * rng.standard_normal(self.drift.shape[0])
        self.X = self._feasible(X)
        self.logP = self.logP + st.param_walk_per_sqrt_h * math.sqrt(dt_h) * rng.standard_normal(self.logP.shape)
        self.t_h += dt_h
        self.pending_h += dt_h
        f_rest = st.rest_noise_fraction
        self.pending_model_h += dt_h if f_rest == 1.0 else mill_h + f_rest * (dt_h - mill_h)

    def reading_prediction(self) -> tuple[float, float]:
        """Weighted mean and sd (degC) of the vial temperature a reading now is expected at, before the
        reading's own noise: the particles' spread and the change of the heating gain the reading will
        weigh in (its prior at the first reading, the walk since the last one; a jump, the rare event
        a far reading signals, is left out)."""
        st, w = self.settings, self.weights
        T = self.X[:, 4]
        m = float(w @ T)
        v = st.thermal_gain_walk_per_sqrt_h**2 * self.pending_h + self.gain_var
        var = float(w @ (T - m) ** 2) + v * float(w @ self._excess() ** 2)  # y = T + c E (_reading_update)
        return m, math.sqrt(max(var, 0.0))

    def _excess(self) -> np.ndarray:
        """The card law's temperature excess over ambient of every particle, (T - T_amb) / g (degC)."""
        return (self.X[:, 4] - self.ambient_c) / self.gain

    def _gain_and_temperatures(self, gain: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """New gains (kept >= GAIN_MIN) and the temperatures they give at the particles' card-law excess."""
        gain = np.maximum(gain, GAIN_MIN)
        return gain, self.ambient_c + gain * self._excess()

    def _set_gain(self, gain: np.ndarray) -> None:
        """New gains (kept >= GAIN_MIN); the temperatures follow at the same card-law excess."""
        self.gain, self.X[:, 4] = self._gain_and_temperatures(gain)

    def _moment_noise(self, rng: np.random.Generator, tau_m: float) -> np.ndarray:
        """Factors (N, 4) of the moments' discrepancy noise over ``tau_m`` hours, drawn from its prior."""
        return np.exp(self.q * math.sqrt(tau_m) * rng.standard_normal((self.X.shape[0], N_MOMENTS)))

    def _with_pending_noise(self, rng: np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Copies of the particles and heating gains with the deferred process noise drawn from its
        prior (no sample to guide it), from ``rng`` (default: a copy of the filter's generator, so the
        filter itself, its generator included, is left as it was)."""
        tau, tau_m = self.pending_h, self.pending_model_h
        if rng is None:
            rng = np.random.Generator(type(self.rng.bit_generator)())
            rng.bit_generator.state = self.rng.bit_generator.state
        X = self.X.copy()
        X[:, :N_MOMENTS] *= self._moment_noise(rng, tau_m)
        gain = self.gain
        if tau > 0:  # the vial's gain walks on wall hours (none left after a reading)
            walk = self.settings.thermal_gain_walk_per_sqrt_h * math.sqrt(tau)
            gain, X[:, 4] = self._gain_and_temperatures(gain + walk * rng.standard_normal(X.shape[0]))
        return self._feasible(X), gain

    # --- update -----------------------------------------------------------------------------
    def update(self, s_um=None, r=None, temperature_c: float | None = None) -> Estimate:
        """Weight particles by a micrograph sample and/or a temperature reading; resample if needed.

        Parameters
        ----------
        s_um, r : array_like, optional
            Measured sizes (um, > 0) and aspect ratios ([0, 1)) of one sample.
        temperature_c : float, optional
            Vial-temperature reading (degC).

        Raises
        ------
        bmctl.errors.InputError
            What ``run_filter`` refuses (:func:`bmctl.estimate.filter.check_update`): no particles,
            unequal numbers of s and r, a size outside 1e-3 .. 1e4 um, r outside [0, 1), a reading
            outside [-50 degC, the card's melting limit]; nothing is changed then.
        """
        st, rng = self.settings, self.rng
        reading, raster = check_update(self.model, s_um, r, temperature_c, st.law)
        N = self.X.shape[0]
        tau, tau_m = self.pending_h, self.pending_model_h
        logw = self.logw.copy()
        eta = np.array([np.nan, np.nan])
        n_meas = 0
        impossible = False  # the sample at the likelihood's floor under every particle

        # vial temperature: the heating gain's change (walk, its prior at the first reading, or a
        # jump) x the Gaussian reading, linear in the change -> its exact posterior as proposal
        v_walk = st.thermal_gain_walk_per_sqrt_h**2 * tau
        if reading is not None:
            logw += self._reading_update(reading, v_walk)
        elif v_walk > 0:
            self._set_gain(self.gain + math.sqrt(v_walk) * rng.standard_normal(N))

        if raster is not None:
            n_meas = raster.n
            logw_s, eta, impossible = self._sample_update(raster, tau_m)
            logw += logw_s
            self.feed_open = False
        elif tau_m > 0 and st.moment_noise_at == "update":
            self.X[:, :N_MOMENTS] *= self._moment_noise(rng, tau_m)
        self.X = self._feasible(self.X)
        self.pending_h = 0.0
        if raster is not None or st.moment_noise_at == "update":
            self.pending_model_h = 0.0

        degenerate = False
        if impossible or not np.any(np.isfinite(logw)):
            degenerate = True  # every particle impossible: keep the prior weights, report it
            self.n_degenerate += 1
            logw = self.logw.copy()
        logw = np.where(np.isfinite(logw), logw, -np.inf)
        self.logw = logw - _logsumexp(logw)
        ess = effective_sample_size(self.weights)
        resampled = False
        if ess < st.ess_fraction * N:
            self._resample()
            resampled = True
        est = self.estimate()  # the moments' noise still deferred ("sample") shown, not spent
        est.ess, est.resampled, est.degenerate = ess, resampled, degenerate
        est.eta, est.n_measured = tuple(float(e) for e in eta), n_meas
        return est

    def _reading_update(self, y: float, v_walk: float) -> np.ndarray:
        """Draw the gain's change given a reading ``y`` (degC); returns the log-weights (predictive density).

        The reading is y = T + c E + e, c the gain's change, E the card-law excess, e ~ N(0, s^2).
        With c ~ sum_k pi_k N(0, v_k), the predictive is sum_k pi_k N(y; T, E^2 v_k + s^2) and the
        posterior of c a mixture of the Gaussians N(v_k E (y - T) / S_k, v_k s^2 / S_k).
        """
        st, rng = self.settings, self.rng
        N = self.X.shape[0]
        E = self._excess()
        s2 = st.sigma_temperature_c**2
        prior = st.thermal_gain_prior_std**2
        if self.gain_var > 0:  # the first reading: the gain's prior
            comps = [(1.0, v_walk + self.gain_var)]
            self.gain_var = 0.0
        elif st.thermal_gain_jump_prob > 0 and prior > 0:
            comps = [(1.0 - st.thermal_gain_jump_prob, v_walk), (st.thermal_gain_jump_prob, v_walk + prior)]
        else:
            comps = [(1.0, v_walk)]
        resid = y - self.X[:, 4]
        S = [E**2 * v + s2 for _, v in comps]
        logc = np.array([math.log(pi) - 0.5 * resid**2 / Sk - 0.5 * np.log(2 * math.pi * Sk)
                         for (pi, _), Sk in zip(comps, S)])
        lse = np.logaddexp.reduce(logc, axis=0)
        k = np.zeros(N, dtype=int)
        if len(comps) > 1:
            k = (rng.random(N) < np.exp(logc[1] - lse)).astype(int)
        v = np.array([c[1] for c in comps])[k]
        Sk = np.choose(k, S)
        mean = v * E * resid / Sk
        sd = np.sqrt(v * s2 / Sk)
        self._set_gain(self.gain + mean + sd * rng.standard_normal(N))
        return lse

    def _sample_update(self, raster: Raster, tau: float):
        """Guided proposal of the log moments and the importance log-weights of one sample."""
        st, rng = self.settings, self.rng
        N = self.X.shape[0]
        M = np.log(self.X[:, :N_MOMENTS])  # prior means (noise-free predictions)
        fit = fit_sample(raster, st.law)
        self.last_fit = fit
        eta = learning_rates(fit, st)
        eta_vec = np.repeat(eta, 2)
        if st.adapt and tau > 0:
            self._adapt(fit, M, tau, eta_vec)
        qvar = self.q**2 * tau  # (4,) discrepancy variance
        if self.feed_open:  # a sample of the feed: its moments' prior beyond the card's, where the sample fits
            qvar = np.maximum(qvar + st.feed_log_std**2 * np.repeat(fit.ok, 2), FEED_VAR_FLOOR)
        moved = bool(np.any(qvar > 0))

        if moved and st.proposal == "bootstrap":
            Z = M + rng.standard_normal((N, N_MOMENTS)) * np.sqrt(qvar)[None, :]
            corr = np.zeros(N)
        elif moved:
            # block-diagonal Gaussian proposal; a block without a proper fit falls back to the prior
            A = np.diag(np.sqrt(eta_vec)) @ fit.info @ np.diag(np.sqrt(eta_vec))  # eta-tempered information
            for b in range(2):
                if not fit.ok[b]:
                    A[2 * b:2 * b + 2, :] = 0.0
                    A[:, 2 * b:2 * b + 2] = 0.0
            Qinv = np.diag(1.0 / qvar)
            S = np.linalg.inv(Qinv + A)
            S = 0.5 * (S + S.T)
            L = np.linalg.cholesky(S)
            mu = (M * (1.0 / qvar)[None, :] + (A @ fit.z)[None, :]) @ S
            use_prior = rng.random(N) < st.defensive
            eps = rng.standard_normal((N, N_MOMENTS))
            Z = np.where(use_prior[:, None], M + eps * np.sqrt(qvar)[None, :], mu + eps @ L.T)
            log_prior = _mvn_logpdf_diag(Z - M, qvar)
            log_guided = _mvn_logpdf_chol(Z - mu, L)
            log_q = np.logaddexp(math.log(st.defensive) + log_prior if st.defensive > 0 else -np.inf,
                                 math.log1p(-st.defensive) + log_guided)
            corr = log_prior - log_q
        else:
            Z = M
            corr = np.zeros(N)
        X = self.X.copy()
        X[:, :N_MOMENTS] = np.exp(Z)
        X = self._feasible(X)
        ls, lr = loglik_raster(raster, X[:, 0], X[:, 1], X[:, 2], X[:, 3], st.law)
        self.X = X
        # every measured size (or every r) in a cell of probability 0 (the floor) under every particle:
        # no particle explains the sample, the floored weights would carry the proposal alone
        floor = raster.n * LOG_P_FLOOR * (1.0 - 1e-9)
        impossible = bool(np.all((ls <= floor) | (lr <= floor)))
        return eta[0] * ls + eta[1] * lr + corr, eta, impossible

    def _adapt(self, fit, M: np.ndarray, tau: float, eta_vec: np.ndarray) -> None:
        """Innovation-based update of the discrepancy noise (one scalar per log moment)."""
        st = self.settings
        w = self.weights
        mbar = w @ M
        var_m = w @ (M - mbar) ** 2
        meas_var = np.full(N_MOMENTS, np.inf)
        for b in range(2):
            sl = slice(2 * b, 2 * b + 2)
            if fit.ok[b] and eta_vec[2 * b] > 0:
                meas_var[sl] = np.diag(np.linalg.inv(eta_vec[2 * b] * fit.info[sl, sl]))
        innov2 = (fit.z - mbar) ** 2
        ok = np.repeat(fit.ok, 2) & np.isfinite(meas_var)
        q2_new = np.maximum(innov2 - var_m - meas_var, 0.0) / tau
        q2 = (1 - st.adapt_rate) * self.q**2 + st.adapt_rate * q2_new
        q = np.clip(np.sqrt(q2), np.asarray(st.process_noise_floor, dtype=float), st.process_noise_max)
        self.q = np.where(ok, q, self.q)

    def _resample(self) -> None:
        st, rng = self.settings, self.rng
        idx = resample(self.weights, rng, st.scheme)
        self.X = self.X[idx].copy()
        self.logP = self.logP[idx].copy()
        self.gain = self.gain[idx].copy()
        self.drift = self.drift[idx].copy()
        N, d = self.logP.shape
        spread = self.logP.max(axis=0) - self.logP.min(axis=0)
        self.logP += st.roughening * np.maximum(spread, 1e-3) * N ** (-1.0 / d) * rng.standard_normal((N, d))
        if st.size_drift_prior_per_h > 0:
            spread_b = float(self.drift.max() - self.drift.min())
            self.drift += st.roughening * max(spread_b, 1e-4) / N * rng.standard_normal(N)
        self.logw = np.full(N, -np.log(N))
        self.n_resampled += 1

    # --- read-out ---------------------------------------------------------------------------
    def _summary(self, X: np.ndarray | None = None, gain: np.ndarray | None = None) -> Estimate:
        """The estimate of particles ``X`` with heating gains ``gain`` (default: the filter's own)."""
        X = self.X if X is None else X
        gain = self.gain if gain is None else gain
        w = self.weights
        V = np.hstack([X, self.P])
        q = weighted_quantiles(V, w)
        qg = weighted_quantiles(gain[:, None], w)
        extra = {"thermal_gain": (float(w @ gain), float(qg[0, 0]), float(qg[1, 0]))}
        if self.settings.size_drift_prior_per_h > 0:
            qd = weighted_quantiles(self.drift[:, None], w)
            extra["size_drift_per_h"] = (float(w @ self.drift), float(qd[0, 0]), float(qd[1, 0]))
        return Estimate(self.t_h, self.names, w @ V, q[0], q[1], effective_sample_size(w),
                        size_stats=particle_size_stats(self.model, X, w), extra=extra)

    def estimate(self) -> Estimate:
        """Weighted mean and 90 % interval of every state and parameter, the process noise deferred
        since the last update included.

        With ``moment_noise_at = "sample"`` reading the estimate changes nothing: the deferred noise
        is drawn on copies of the particles from a copy of the filter's generator and stays deferred,
        so the next sample's guided proposal still has it, and how often the estimate is read does
        not change what the filter does. With ``"update"`` (the default) the read draws the deferred
        noise into the particles from its prior, as an update without a sample would.
        """
        if self.pending_h <= 0 and self.pending_model_h <= 0:
            return self._summary()
        if self.settings.moment_noise_at == "sample":
            return self._summary(*self._with_pending_noise())
        self.X, self.gain = self._with_pending_noise(self.rng)  # spent: the next update starts afresh
        self.pending_h = self.pending_model_h = 0.0
        return self._summary()


def learning_rates(fit, st: FilterSettings) -> np.ndarray:
    """Power-likelihood learning rate of the size and shape blocks of one sample.

    Parameters
    ----------
    fit : SampleFit
        The sample's own fit (information, calibrated rates).
    st : FilterSettings
        Cap ``learning_rate``, ``calibrate_learning_rate`` and the law's misfit floor.

    Returns
    -------
    ndarray, (2,)

    Notes
    -----

    eta = eta_LHW * min_k v_k / (v_k + tau_k^2): the Lyddon-Holmes-Walker calibration
    ``fit.eta`` (capped by ``st.learning_rate``), reduced so that the tempered variance of
    every log moment k of the block, v_k / eta, is at least its sampling variance v_k (from
    the calibrated information) plus the law-misfit floor tau_k^2. Small samples keep
    eta ~ eta_LHW; as n grows the sample's information is capped at ~1 / tau^2.
    """
    base = np.minimum(fit.eta if st.calibrate_learning_rate else np.ones(2), st.learning_rate)
    tau2 = st.law.misfit_floor**2
    out = base.copy()
    for b in range(2):
        if not fit.ok[b] or base[b] <= 0:
            continue
        sl = slice(2 * b, 2 * b + 2)
        v = np.diag(np.linalg.inv(base[b] * fit.info[sl, sl]))
        out[b] = base[b] * float(np.min(v / (v + tau2[sl])))
    return out


def _mvn_logpdf_diag(d: np.ndarray, var: np.ndarray) -> np.ndarray:
    return -0.5 * np.sum(d * d / var[None, :], axis=1) - 0.5 * np.sum(np.log(2 * np.pi * var))


def _mvn_logpdf_chol(d: np.ndarray, L: np.ndarray) -> np.ndarray:
    y = np.linalg.solve(L, d.T)
    return -0.5 * np.sum(y * y, axis=0) - np.sum(np.log(np.diag(L))) - 0.5 * d.shape[1] * math.log(2 * math.pi)
