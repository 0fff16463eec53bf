"""Identification of the moment model from plant experiments, and its validation.

1. :func:`design` lays out plant experiments on a 0.5-h grid: constant speeds across the
   mill's range, interrupted milling (duty < 1), speed steps and rests, branches from
   states reached under another schedule (run, snapshot, branch), and random
   piecewise-constant schedules; :func:`validation_design` draws held-out random schedules
   from an independent stream.
2. :func:`run_experiments` runs each on an ensemble of seeded plants and keeps the
   ensemble mean (and spread) of the moments after every interval.
3. :func:`fit` fits the free coefficients (coeffs.SPEC) by least squares on the
   simulation error of the whole trajectories, range-normalised (:func:`run_scales`); exact derivatives come
   from casadi (the same equations, with the coefficients as symbols).
4. :func:`nrmse_table` compares predictions and ensemble means on held-out schedules.

NRMSE of a moment on one schedule = RMSE(model - plant mean over the recorded times) /
(max - min of the plant-mean trajectory of that moment over the schedule, floored at
10 % of its mean); the table reports the mean over schedules (and the worst).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Callable, Sequence

import numpy as np

from ..config import ModelCard
from . import coeffs as cf
from .model import MomentModel

DT_H = 0.5  # interval of the experiments (h)
HOURS = 12.0
MOMENTS = ("s_mean_um", "s_std_um", "r_mean", "r_std", "temperature_c", "hardening")
FIT_IDX = (0, 1, 2, 3)
N_RANDOM_TRAIN = 16  # random schedules in the training design (docs/moments.md, Sec. 6)
#: (gamma, delta) factors of the training plants off the card, and random schedules on each
TRAIN_FACTORS = ((1.15, 0.85), (0.85, 1.15))
N_RANDOM_OFF_CARD = 3
#: plant seeds of the training ensemble (offsets to 1000 x --seed). Four seeds instead of two halve the
#: variance of the ensemble means the fit chases; on three held-out sets the lab card's r_std fell by
#: 0.07-0.14 points and no fan entry moved by more than 0.06 (docs/moments.md, Sec. 6)
TRAIN_SEEDS = (1, 2, 3, 4)
#: plant seeds of the held-out validation ensemble (offsets to 1000 x --seed)
VALID_SEEDS = (11, 12, 13)
N_VALID = 72  # held-out random schedules: the standard error of their mean NRMSE is 0.08-0.35 points (24: 0.3-0.8)


@dataclass
class Spec:
    """One experiment: an optional prefix schedule (run, then branch) and the recorded inputs.

    ``prefix`` and ``inputs`` are lists of (rpm, milling) per DT_H interval; the record
    starts after the prefix.
    """

    name: str
    inputs: list[tuple[float, float]]
    prefix: list[tuple[float, float]] = field(default_factory=list)
    #: (gamma, delta) of the plant relative to the card; the model runs with p = factors
    factors: tuple[float, float] = (1.0, 1.0)


@dataclass
class Experiment:
    """A run of the plant ensemble: inputs, ensemble-mean states and spread after every interval."""

    name: str
    U: np.ndarray  # (K, 2)
    Y: np.ndarray  # (K + 1, 6) ensemble mean, x0 first
    S: np.ndarray  # (K + 1, 6) ensemble std across seeds
    dt_h: float = DT_H
    p: np.ndarray = field(default_factory=lambda: np.ones(2))  # the plant's (gamma, delta) factors
    #: (K, 2) ensemble-mean bonding and fracture events per particle in each interval (the fit
    #: does not use them; benchmarks/moments_events.py compares them with the model's)
    events: np.ndarray | None = None

    @property
    def x0(self) -> np.ndarray:
        return self.Y[0]


def _grid(segments: Sequence[tuple[float, float, float]]) -> list[tuple[float, float]]:
    """(hours, rpm, milling) segments -> per-interval (rpm, milling) on the DT_H grid."""
    from ..schedule import Schedule

    return Schedule.from_pairs(segments).grid(DT_H)


def random_schedule(rng: np.random.Generator, rpm_max: float, hours: float = HOURS, rest_p: float = 0.2,
                    lo_frac: float = 1 / 6) -> list[tuple[float, float]]:
    """Random piecewise-constant rpm on the DT_H grid: segments of 1-3 h, uniform rpm, some rests."""
    segs, t = [], 0.0
    while t < hours - 1e-9:
        h = min(float(rng.choice([1.0, 1.5, 2.0, 2.5, 3.0])), hours - t)
        if rng.random() < rest_p and t > 0:
            segs.append((h, 0.0, 1.0))
        else:
            segs.append((h, round(float(rng.uniform(lo_frac, 1.0)) * rpm_max / 10) * 10, 1.0))
        t += h
    return _grid(segs)


def design(card: ModelCard, seed: int = 0, quick: bool = False, n_random: int | None = None) -> list[Spec]:
    """Training experiments for ``card`` (speeds as fractions of the mill's rpm_max).

    ``n_random`` random schedules close the design (default :data:`N_RANDOM_TRAIN`, 2 with
    ``quick``). They come from one stream, so a larger ``n_random`` keeps the first schedules
    of a smaller one and adds more.
    """
    R = card.mill.rpm_max
    r = lambda f: round(f * R / 10) * 10  # noqa: E731
    specs = [Spec(f"const-{r(f):g}", _grid([(HOURS, r(f), 1.0)])) for f in ((1 / 6, 1 / 3, 1 / 2, 2 / 3, 5 / 6, 1.0)
                                                                            if not quick else (1 / 4, 1 / 2, 3 / 4, 1.0))]
    specs += [
        Spec(f"duty-{r(2 / 3):g}-0.75", _grid([(HOURS, r(2 / 3), 0.75)])),
        Spec(f"duty-{r(1.0):g}-0.5", _grid([(HOURS, r(1.0), 0.5)])),
        Spec(f"step-{r(1 / 3):g}-{r(5 / 6):g}", _grid([(6, r(1 / 3), 1.0), (6, r(5 / 6), 1.0)])),
        Spec(f"step-{r(5 / 6):g}-{r(1 / 4):g}", _grid([(6, r(5 / 6), 1.0), (6, r(1 / 4), 1.0)])),
        Spec(f"rest-{r(1 / 2):g}-{r(3 / 4):g}", _grid([(2, r(1 / 2), 1.0), (2, 0.0, 1.0), (8, r(3 / 4), 1.0)])),
        Spec(f"branch-{r(1 / 2):g}-4h-{r(1 / 4):g}", _grid([(8, r(1 / 4), 1.0)]), _grid([(4, r(1 / 2), 1.0)])),
        Spec(f"branch-{r(1.0):g}-3h-{r(1 / 3):g}", _grid([(9, r(1 / 3), 1.0)]), _grid([(3, r(1.0), 1.0)])),
    ]
    if not quick:
        specs += [
            Spec(f"duty-{r(1 / 2):g}-0.5", _grid([(HOURS, r(1 / 2), 0.5)])),
            Spec(f"branch-{r(1 / 2):g}-4h-{r(1.0):g}", _grid([(8, r(1.0), 1.0)]), _grid([(4, r(1 / 2), 1.0)])),
            Spec(f"branch-{r(1 / 6):g}-6h-{r(2 / 3):g}", _grid([(6, r(2 / 3), 1.0)]), _grid([(6, r(1 / 6), 1.0)])),
        ]
    rng = np.random.default_rng([seed, 1])
    if n_random is None:
        n_random = 2 if quick else N_RANDOM_TRAIN
    for k in range(int(n_random)):
        specs.append(Spec(f"random-train-{k}", random_schedule(rng, R)))
    # plants off the card (TRAIN_FACTORS, half the off-card check's +-30 %): the fit sees how the
    # plant answers gamma and delta, which the particle filter estimates through the model
    # (docs/moments.md, Sec. 6); their schedules come from their own stream [seed, 4]
    grng = np.random.default_rng([seed, 4])
    for g, d in TRAIN_FACTORS:
        specs.append(Spec(f"recipe-g{g:g}-d{d:g}", _grid([(HOURS, card.process.rpm, 1.0)]), factors=(g, d)))
        for k in range(1 if quick else N_RANDOM_OFF_CARD):
            specs.append(Spec(f"random-g{g:g}-d{d:g}-{k}", random_schedule(grng, R), factors=(g, d)))
    return specs


def design_window(card: ModelCard, specs: Sequence[Spec]) -> dict:
    """The ``[window]`` of a coefficient file: the milling speeds of ``specs`` and the steady vial
    temperatures they span (the ambient, which every run starts from, up to the steady temperature of
    the fastest speed; :func:`bmctl.cards.steady_temperature_c`).

    Parameters
    ----------
    card : ModelCard
    specs : sequence of Spec
        The training design.

    Returns
    -------
    dict
        ``rpm`` and ``temperature_c`` as [low, high] lists, and ``source`` (what they are).
    """
    from ..cards import steady_temperature_c

    rpms = [rpm for s in specs for rpm, duty in list(s.prefix) + list(s.inputs) if rpm > 0 and duty > 0]
    lo, hi = min(rpms), max(rpms)
    return {"rpm": [float(lo), float(hi)],
            "temperature_c": [round(card.thermal.ambient_C, 2), round(steady_temperature_c(card, hi), 2)],
            "source": "milling speeds of the training experiments; vial temperatures from the ambient to the "
                      "steady temperature of the fastest (docs/moments.md, Sec. 9)"}


def card_table(card: ModelCard) -> dict:
    """The ``[card]`` table of a coefficient file: name, fingerprint and the fingerprint's values."""
    from ..cards import fingerprint, fingerprint_values

    values = fingerprint_values(card)
    return {"name": card.card.name, "fingerprint": fingerprint(values), "values": values}


def validation_design(card: ModelCard, seed: int = 0, n: int = N_VALID, stream: int = 2) -> list[Spec]:
    """Held-out random schedules from the random stream ``[seed, stream]``, independent of the
    training design's ``[seed, 1]`` (``benchmarks/moments_confirm.py`` draws its confirmation set
    from stream 3)."""
    rng = np.random.default_rng([seed, stream])
    return [Spec(f"random-valid-{k}", random_schedule(rng, card.mill.rpm_max)) for k in range(n)]


#: plant (gamma, delta) factors of the off-card check: the two +-30 % plants of the estimation study
FACTORS = ((1.3, 0.7), (0.7, 1.3))


def off_card_design(card: ModelCard) -> list[Spec]:
    """The off-card check: the card's own recipe (process rpm, 12 h) on plants whose gamma and
    delta are off the card (:data:`FACTORS`). Nothing is fitted on them: they test the derived
    response of the rates to the parameters p = (gamma, delta) factors."""
    rpm = card.process.rpm
    return [Spec(f"recipe-g{g:g}-d{d:g}", _grid([(HOURS, rpm, 1.0)]), factors=(g, d)) for g, d in FACTORS]


def _plant_states(plant) -> np.ndarray:
    m = plant.moments()
    return np.array([m[k] for k in MOMENTS])


def plant_work(card: ModelCard, specs: Sequence[Spec], seeds: int, particles: int) -> tuple[int, float]:
    """(plant runs, estimated CPU seconds) of :func:`run_experiments` (sizes the local cluster)."""
    from ..cards import simulation_work

    cpu_s = 0.0
    for spec in specs:
        segs = [(DT_H * duty, rpm) for rpm, duty in list(spec.prefix) + list(spec.inputs)]
        cpu_s += simulation_work(card, segs, particles, DT_H, raster=False)["cpu_s"]
    return len(specs) * seeds, cpu_s * seeds


def _seed_runs(task: tuple, rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray]]:
    """Every spec of ``task = (card, specs, particles)`` on plants drawn from ``rng``'s state.

    Each plant starts from the state ``rng`` has on entry (common random numbers across specs, as
    ``make_plant(seed=...)`` gives); a prefix is run once, snapshotted and branched.

    Returns
    -------
    list of (trajectory (K + 1, 6), events (K, 2))
        One per spec, in spec order.
    """
    import copy

    from ..config import with_factors
    from ..plant import make_plant

    card, specs, particles = task
    template = copy.deepcopy(rng)  # the seed's initial state; every plant draws from a copy of it
    cards = {f: (card if f == (1.0, 1.0) else with_factors(card, *f)) for f in {tuple(s.factors) for s in specs}}
    prefixes: dict[tuple, dict] = {}
    out = []
    for spec in specs:
        c = cards[tuple(spec.factors)]
        key = (tuple(spec.factors), tuple(spec.prefix))
        if key not in prefixes:
            plant = make_plant(c, particles=particles, rng=copy.deepcopy(template))
            for rpm, duty in spec.prefix:
                plant.advance(rpm, DT_H, duty)
            prefixes[key] = plant.snapshot()
        plant = make_plant(c, particles=particles, rng=copy.deepcopy(template))
        plant.restore(prefixes[key])
        traj, ev = [_plant_states(plant)], []
        for rpm, duty in spec.inputs:
            M, b0, f0 = plant.M, plant.counts.bonds, plant.counts.fractures
            plant.advance(rpm, DT_H, duty)
            traj.append(_plant_states(plant))
            ev.append(((plant.counts.bonds - b0) / M, (plant.counts.fractures - f0) / M))
        out.append((np.array(traj), np.array(ev).reshape(-1, 2)))
    return out


def run_experiments(card: ModelCard, specs: Sequence[Spec], seeds: Sequence[int], particles: int,
                    progress: Callable[[str], None] | None = None, client=None) -> list[Experiment]:
    """Run every spec on plants seeded with ``seeds`` (prefixes shared: run once, snapshot, branch).

    Parameters
    ----------
    card : ModelCard
        The model card.
    specs : sequence of Spec
        The experiments.
    seeds : sequence of int
        Plant seeds: every spec runs on a plant drawn from ``default_rng(seed)`` for each seed.
    particles : int
        Simulated particles per plant.
    progress : callable, optional
        Called with a line ("k/N plant runs") as each run finishes.
    client : distributed.Client, optional
        Dask engine from :func:`bmctl.parallel.client_for`; None runs serially in this process.
        The result is the same either way.

    Returns
    -------
    list of Experiment
        One per spec: ensemble mean and spread over the seeds.
    """
    from ..parallel import map_seeded

    seeds = [int(sd) for sd in seeds]
    # one task per (seed, spec): every plant starts from its seed's initial state, so splitting a
    # seed's specs over tasks changes no number (a branch re-runs its own prefix) and the ensemble
    # spreads over as many workers as there are runs
    tasks = [(card, [spec], int(particles)) for _ in seeds for spec in specs]
    done = iter(range(1, len(tasks) + 1))
    report = None if progress is None else (lambda _: progress(f"{next(done)}/{len(tasks)} plant runs"))
    # SeedSequence(sd) seeds the same generator as default_rng(sd), i.e. make_plant(seed=sd)
    flat = map_seeded(_seed_runs, tasks, [np.random.SeedSequence(sd) for sd in seeds for _ in specs], client,
                      report)
    per_seed = [[r[0] for r in flat[k * len(specs):(k + 1) * len(specs)]] for k in range(len(seeds))]
    out = []
    for i, spec in enumerate(specs):
        A = np.stack([runs[i][0] for runs in per_seed])
        out.append(Experiment(spec.name, np.array(spec.inputs, dtype=float), A.mean(0),
                              A.std(0, ddof=1) if A.shape[0] > 1 else np.zeros_like(A[0]),
                              p=np.array(spec.factors, dtype=float),
                              events=np.mean([runs[i][1] for runs in per_seed], axis=0)))
    return out


# --- fitting -------------------------------------------------------------------------------------


def span(Y: np.ndarray) -> np.ndarray:
    """Range of each column of ``Y`` (rows are times), floored at 10 % of its mean (the NRMSE normaliser)."""
    return np.maximum(Y.max(0) - Y.min(0), 0.1 * np.abs(Y.mean(0)) + 1e-12)


def scales(experiments: Sequence[Experiment]) -> np.ndarray:
    """Residual scale per moment: the range over all training data (floored at 10 % of the mean)."""
    return span(np.concatenate([e.Y for e in experiments]))


def run_scales(experiments: Sequence[Experiment]) -> np.ndarray:
    """Residual scale per experiment and moment, ``(len(experiments), 6)``: the geometric mean of the
    experiment's own range (:func:`span`, the held-out NRMSE's normaliser) and the range over all
    experiments (:func:`scales`).

    The own range alone weights runs in which a moment hardly moves as heavily as those with large
    excursions, and trades the shape law's extrapolation to other plants for them; the common range
    alone lets the runs with large excursions drown the rest (docs/moments.md, Sec. 6).
    """
    sc = scales(experiments)
    return np.array([np.sqrt(span(e.Y) * sc) for e in experiments])


class _Sym:
    """casadi simulator of all experiments with the free coefficients as symbols."""

    def __init__(self, model: MomentModel, experiments: Sequence[Experiment], free: Sequence[str], fixed: dict):
        import casadi as ca

        from . import equations as eq

        self.free = list(free)
        th = ca.SX.sym("theta", len(self.free))
        q = dict(fixed)
        for i, k in enumerate(self.free):
            q[k] = th[i]
        _, rates = eq.casadi_rate_field(model.const, q, theta=th)
        x = ca.SX.sym("x", 6)
        u = ca.SX.sym("u", 2)
        p = ca.SX.sym("p", 2)
        dt = experiments[0].dt_h
        n, s = model._integration(dt)
        out = eq.step(eq.CA(), model.const, q, [x[i] for i in range(6)], [u[0], u[1]], [p[0], p[1]], dt, n, s,
                      rates=rates)
        F = ca.Function("step_q", [x, u, p, th], [ca.vertcat(*out)])
        thM = ca.MX.sym("theta", len(self.free))
        res = []
        self.scale = None
        for e in experiments:
            K = e.U.shape[0]
            sim = F.mapaccum("sim", K, [0], [0])
            X = sim(e.x0, e.U.T, e.p, ca.repmat(thM, 1, K))
            res.append(X)
        self.sims = ca.Function("sims", [thM], res)
        self.jac = None
        self._thM = thM
        self._res = res

    def residual_function(self, experiments, sc, weights):
        """casadi Functions of theta: the stacked residuals and their Jacobian. ``sc`` is the
        residual scale per experiment and moment (:func:`run_scales`)."""
        import casadi as ca

        parts = []
        for X, e, sce in zip(self._res, experiments, sc):
            for j in FIT_IDX:
                parts.append(((X[j, :] - e.Y[1:, j][None, :]) / sce[j] * weights[j]).T)
        r = ca.vertcat(*parts)
        f = ca.Function("r", [self._thM], [r])
        J = ca.Function("J", [self._thM], [ca.jacobian(r, self._thM)])
        return f, J


#: coefficients fitted by default (the rest keep their defaults)
FREE = ("bond_log_scale", "bond_slope", "bond_offset", "frac_log_scale", "frac_slope", "frac_offset",
        "round_log_scale", "round_size_bias", "round_var_log_scale", "round_rpm_slope",
        "round_var_rpm_slope", "bond_ds_gain", "frac_ds_gain", "bond_r_gain", "frac_r_gain", "r_var_gain",
        "r_size_corr", "frac_link_shift", "r_link_cv_slope", "frac_link_cv_shift", "bond_rpm_slope",
        "frac_rpm_slope")


@dataclass
class FitResult:
    coeffs: dict
    cost0: float
    cost: float
    nfev: int
    seconds: float
    message: str


def fit(model: MomentModel, experiments: Sequence[Experiment], free: Sequence[str] = FREE,
        weights: Sequence[float] = (1.0, 1.0, 1.0, 1.0), max_nfev: int = 80,
        log: Callable[[str], None] | None = None) -> FitResult:
    """Least-squares fit of ``free`` coefficients on range-normalised simulation errors (:func:`run_scales`)."""
    from scipy.optimize import least_squares

    t0 = time.time()
    fixed = {k: v for k, v in model.coeffs.items() if k not in free}
    sym = _Sym(model, experiments, free, fixed)
    sc = run_scales(experiments)
    w = np.ones(6)
    w[list(FIT_IDX)] = weights
    f, J = sym.residual_function(experiments, sc, w)
    th0 = np.array([model.coeffs[k] for k in free])
    lo = np.array([cf.SPEC[k][1] for k in free])
    hi = np.array([cf.SPEC[k][2] for k in free])
    th0 = np.clip(th0, lo + 1e-9, hi - 1e-9)
    count = [0]

    def fun(th):
        count[0] += 1
        v = np.array(f(th)).ravel()
        return np.where(np.isfinite(v), v, 1e3)

    def jac(th):
        Jv = np.array(J(th))
        return np.where(np.isfinite(Jv), Jv, 0.0)

    r0 = fun(th0)
    cost0 = 0.5 * float(r0 @ r0)
    if log:
        log(f"fit: {len(free)} coefficients, {r0.size} residuals, initial cost {cost0:.4g}")
    sol = least_squares(fun, th0, jac=jac, bounds=(lo, hi), method="trf", x_scale="jac", max_nfev=max_nfev,
                        ftol=1e-8, xtol=1e-10)
    out = dict(model.coeffs)
    out.update({k: float(v) for k, v in zip(free, sol.x)})
    if log:
        log(f"fit: cost {cost0:.4g} -> {sol.cost:.4g} in {sol.nfev} evaluations ({time.time() - t0:.1f} s)")
    return FitResult(out, cost0, float(sol.cost), int(sol.nfev), time.time() - t0, str(sol.message))


# --- validation ----------------------------------------------------------------------------------


def predict(model: MomentModel, e: Experiment) -> np.ndarray:
    """Moment-model trajectory from the experiment's initial (ensemble-mean) state."""
    return model.simulate(e.x0, e.U, e.dt_h, p=e.p)


def nrmse(pred: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Per-moment NRMSE: RMSE / (range of the plant-mean trajectory, floored at 10 % of its mean)."""
    rmse = np.sqrt(np.mean((pred[1:] - Y[1:]) ** 2, axis=0))
    return rmse / span(Y)


def nrmse_table(model: MomentModel, experiments: Sequence[Experiment]) -> dict:
    """{'rows': per-experiment NRMSE (K x 6), 'mean': mean over experiments, 'max': worst,
    'preds': the predicted trajectories}."""
    preds = [predict(model, e) for e in experiments]
    rows = np.array([nrmse(P, e.Y) for P, e in zip(preds, experiments)])
    return {"names": [e.name for e in experiments], "rows": rows, "mean": rows.mean(0), "max": rows.max(0),
            "preds": preds}


# --- the whole identification (``bmctl identify``) -----------------------------------------------


def default_particles(quick: bool = False) -> int:
    """Simulated particles per plant of an identification (``--particles`` default)."""
    return 2000 if quick else 4000


@dataclass
class Identification:
    """What :func:`identify` produced: the coefficients, the validation tables and the file text."""

    card_name: str
    coeffs: dict
    fit: FitResult
    valid: list  # held-out experiments
    table: dict  # nrmse_table of the fitted model on the held-out schedules
    table_defaults: dict  # ... of the built-in defaults
    table_train: dict  # ... of the fitted model on the training experiments
    off_card: dict  # ... on off-card plants, told their factors
    off_card_p1: dict  # ... not told (p = 1)
    validation: dict  # the [validation] table of the coefficient file
    meta: dict  # the [identification] table
    toml: str  # the coefficient file


def _per_run(tab: dict, names) -> dict:
    """{"<run>, <moment>": NRMSE} for the runs of an nrmse_table."""
    return {f"{n}, {k}": round(float(v), 5) for n, row in zip(tab["names"], tab["rows"]) for k, v in zip(names, row)}


def check_finite(source: str, experiments: Sequence[Experiment], coeffs: dict) -> None:
    """InputError naming ``source`` when a plant moment or a fitted coefficient is not finite."""
    from ..errors import InputError

    for e in experiments:
        if not np.all(np.isfinite(e.Y)):
            raise InputError(f"{source}: the plant produced non-finite moments in {e.name}")
    if not all(np.isfinite(v) for v in coeffs.values()):
        raise InputError(f"{source}: identification produced non-finite coefficients")


def identify(card: ModelCard, seed: int = 0, quick: bool = False, particles: int | None = None,
             random_schedules: int | None = None, source: str = "", command: str = "",
             log: Callable[[str], None] | None = None, client=None) -> Identification:
    """Fit the moment model of ``card`` to a design of plant experiments and validate it.

    Parameters
    ----------
    card : ModelCard
        The model card.
    seed : int, optional
        Seed of the plant ensembles and the design (seeds are offsets to 1000 x seed).
    quick : bool, optional
        Fewer experiments and one training seed.
    particles : int, optional
        Simulated particles per plant (default 4000; quick 2000).
    random_schedules : int, optional
        Random schedules in the training design (default :data:`N_RANDOM_TRAIN`).
    source : str, optional
        Name of the card (and of the coefficient file) in messages and in the model's label.
    command : str, optional
        The command line that regenerates the file (recorded in ``[identification]``).
    log : callable, optional
        Progress lines.
    client : distributed.Client, optional
        Dask engine of the plant runs (:func:`bmctl.parallel.client_for`); None: serial, in
        process. The result is the same either way.
    """
    from datetime import datetime, timezone

    from .model import default_coeffs

    log = log or (lambda msg: None)
    particles = particles or default_particles(quick)
    train_seeds = [1000 * seed + k for k in ((1,) if quick else TRAIN_SEEDS)]
    valid_seeds = [1000 * seed + k for k in ((11, 12) if quick else VALID_SEEDS)]
    specs = design(card, seed, quick, random_schedules)
    vspecs = validation_design(card, seed, 4 if quick else N_VALID)
    log(f"{card.card.name}: {len(specs)} training experiments x {len(train_seeds)} seeds, "
        f"{len(vspecs)} held-out schedules x {len(valid_seeds)} seeds, M={particles}")
    train = run_experiments(card, specs, train_seeds, particles, client=client)
    log("training experiments done")
    valid = run_experiments(card, vspecs, valid_seeds, particles, client=client)
    off = run_experiments(card, off_card_design(card), valid_seeds, particles, client=client)
    log("held-out experiments done")

    model0 = MomentModel(card, default_coeffs(card), "defaults")
    res = fit(model0, train, log=log)
    model = MomentModel(card, res.coeffs, source)
    check_finite(source, train + valid + off, res.coeffs)
    tab0, tab, tab_train = nrmse_table(model0, valid), nrmse_table(model, valid), nrmse_table(model, train)
    # off-card check: the model told the plant's (gamma, delta) factors, and not told (p = 1)
    otab = nrmse_table(model, off)
    otab1 = nrmse_table(model, [replace(e, p=np.ones(2)) for e in off])
    log("validation done")

    names = MOMENTS[:5]
    validation = {
        "definition": "NRMSE = RMSE(model - plant ensemble mean) / range of the plant-mean trajectory "
                      "(floored at 10 % of its mean), per held-out schedule; mean and max over schedules",
        "schedules": len(valid), "seeds": valid_seeds, "particles": particles,
        "mean": {k: round(float(v), 5) for k, v in zip(names, tab["mean"])},
        "max": {k: round(float(v), 5) for k, v in zip(names, tab["max"])},
        "defaults_mean": {k: round(float(v), 5) for k, v in zip(names, tab0["mean"])},
        "off_card": _per_run(otab, names[:4]),
        "off_card_p1": _per_run(otab1, names[:4]),
    }
    meta = {
        "card": card.card.name, "command": command,
        "date_utc": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "experiments": len(train), "train_seeds": train_seeds, "particles": particles,
        "dt_h": DT_H, "cost_initial": round(res.cost0, 6), "cost_final": round(res.cost, 6),
        "evaluations": res.nfev, "fit_seconds": round(res.seconds, 1),
    }
    sections = {"card": card_table(card), "window": design_window(card, specs), "identification": meta,
                "validation": validation}
    text = cf.toml_text(res.coeffs, sections,
                        header=f"Moment-model coefficients of {card.card.name}, written by `bmctl identify`.\n"
                               "Re-run the command in [identification] to regenerate; docs/moments.md explains them.")
    return Identification(card.card.name, res.coeffs, res, valid, tab, tab0, tab_train, otab, otab1, validation,
                          meta, text)
