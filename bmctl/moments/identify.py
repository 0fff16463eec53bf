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

import math
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
#: (gamma, delta) factors of the training plants off the card, and random schedules on each (a factor
#: that would take the card's gamma or delta past its field's upper limit is cut there: :func:`plant_factors`)
TRAIN_FACTORS = ((1.15, 0.85), (0.85, 1.15))
N_RANDOM_OFF_CARD = 3
#: the card fields (``[stochastic]``) that a plant's (gamma, delta) factors multiply (:func:`bmctl.config.with_factors`)
FACTOR_FIELDS = ("gamma_per_um2", "delta_per_um2")
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
    #: (gamma, delta) of the plant relative to the card, as the plant has them (:func:`plant_factors`);
    #: the model runs with p = factors
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


def _field_max(name: str) -> tuple[float, bool]:
    """The upper limit of the ``[stochastic]`` field ``name`` and whether it is excluded (inf: none)."""
    from ..config import Stochastic

    for m in Stochastic.model_fields[name].metadata:
        if getattr(m, "le", None) is not None:
            return float(m.le), False
        if getattr(m, "lt", None) is not None:
            return float(m.lt), True
    return math.inf, False


def plant_seeds(seed: int, n_seeds: int, quick: bool = False) -> tuple[list[int], list[int]]:
    """The plant seeds of the training ensemble (``1000 seed + 1 ... n_seeds``) and of the held-out
    and off-card ones (:data:`VALID_SEEDS`, the first two with ``quick``; moved past the training
    seeds when there are more than 10 of them: a held-out plant is never a training plant).

    Examples
    --------
    >>> plant_seeds(0, 4)
    ([1, 2, 3, 4], [11, 12, 13])
    >>> plant_seeds(1, 12, quick=True)
    ([1001, 1002, 1003, 1004, 1005, 1006, 1007, 1008, 1009, 1010, 1011, 1012], [1013, 1014])
    """
    train = [1000 * seed + k for k in range(1, n_seeds + 1)]
    shift = max(0, n_seeds - (VALID_SEEDS[0] - 1))
    return train, [1000 * seed + k + shift for k in (VALID_SEEDS[:2] if quick else VALID_SEEDS)]


def plant_factors(card: ModelCard, factors: Sequence[float]) -> tuple[float, float]:
    """The (gamma, delta) factors of a plant off ``card``: ``factors``, each cut where it would take the
    card's field past its upper limit (``stochastic.gamma_per_um2`` and ``delta_per_um2`` lie in (0, 1]
    µm^-2), so that the plant sits at the limit.

    The plant (:func:`bmctl.config.with_factors`) stays a valid card, and the factor returned is the one
    the plant has, which the experiment records and the model runs with (p = the factors): the fit stays
    consistent. The other factor keeps its full step, so the design still excites the response to it.
    Cards far from the limit (every shipped card) get ``factors`` unchanged.

    Parameters
    ----------
    card : ModelCard
    factors : (float, float)
        Multipliers of gamma and delta (positive).

    Returns
    -------
    (float, float)

    Examples
    --------
    >>> from bmctl.config import load_card
    >>> card = load_card("models/alni-1to1-300rpm-lab.toml")
    >>> plant_factors(card, (1.3, 0.7))
    (1.3, 0.7)
    >>> near = card.model_copy(update={"stochastic": card.stochastic.model_copy(update={"gamma_per_um2": 0.95})})
    >>> g, d = plant_factors(near, (1.3, 0.7))
    >>> round(g, 6), d, 0.95 * g <= 1.0
    (1.052632, 0.7, True)
    """
    out = []
    for name, f in zip(FACTOR_FIELDS, factors):
        v, f = float(getattr(card.stochastic, name)), float(f)
        hi, excluded = _field_max(name)

        def past(x: float) -> bool:  # the plant's value, v * x, as with_factors multiplies
            return v * x >= hi if excluded else v * x > hi

        if past(f):
            f = hi / v
            while past(f):  # the quotient can round up by an ulp
                f = math.nextafter(f, 0.0)
        out.append(f)
    return out[0], out[1]


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


#: the lowest top speed of an identification (rpm): its six constant speeds, 1/6 ... 1 of it on the
#: 10-rpm grid, must be six distinct milling speeds
SPEED_LIMIT_MIN_RPM = 60.0


def speed_limit(card: ModelCard) -> tuple[float, str]:
    """The top speed of the identification's experiments, and a warning line when it is below rpm_max.

    The experiments (training, held-out and off-card) span the speeds up to the mill's rpm_max, unless
    the steady vial temperature there (:func:`bmctl.cards.steady_temperature_c`, the closed form
    T_amb + P(rpm) tau / C) would pass the card's melting limit (:func:`bmctl.cards.melting_limit`),
    which no schedule of any command may cross (:func:`bmctl.cards.check_melting`): then they stop at
    the fastest multiple of 10 rpm whose steady vial stays at or under it. A model trained on a vial
    above the melting point would fit physics nobody runs; its ``[window]`` records the speeds it saw.

    Parameters
    ----------
    card : ModelCard

    Returns
    -------
    (float, str)
        The top speed (rpm) and a one-line warning ("" when it is the mill's rpm_max).

    Raises
    ------
    InputError
        When even :data:`SPEED_LIMIT_MIN_RPM` would pass the melting limit.

    Examples
    --------
    >>> from bmctl.config import load_card
    >>> speed_limit(load_card("models/alni-1to1-300rpm-lab.toml"))  # 349 °C at 600 rpm: under Al's 660 °C
    (600.0, '')
    """
    from ..cards import melting_limit, steady_temperature_c
    from ..errors import InputError

    top = float(card.mill.rpm_max)
    limit, reason = melting_limit(card)
    hot = steady_temperature_c(card, top)
    if hot <= limit:
        return top, ""
    lo, hi = 0.0, top  # the steady temperature rises with the speed (P ~ rpm^3)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if steady_temperature_c(card, mid) <= limit else (lo, mid)
    R = float(math.floor(lo / 10.0 + 1e-9) * 10)
    name = card.card.name
    if R < SPEED_LIMIT_MIN_RPM:
        raise InputError(f"{name}: the steady vial temperature passes {limit:g} °C ({reason}) above {lo:.0f} rpm: "
                         f"too slow a range to identify the moment model on (at least {SPEED_LIMIT_MIN_RPM:g} rpm)")
    return R, (f"{name}: at rpm_max {top:g} rpm the steady vial would reach {hot:.0f} °C, above {limit:g} °C "
               f"({reason}); the identification's experiments mill at {R:g} rpm at most (steady vial "
               f"{card.thermal.ambient_C:g}–{steady_temperature_c(card, R):.0f} °C), and the model warns above "
               "that range")


def design(card: ModelCard, seed: int = 0, quick: bool = False, n_random: int | None = None) -> list[Spec]:
    """Training experiments for ``card`` (speeds as fractions of its top speed: the mill's rpm_max, or
    lower where the steady vial there would pass the melting limit, :func:`speed_limit`).

    ``n_random`` random schedules close the design (default :data:`N_RANDOM_TRAIN`, 2 with
    ``quick``). They come from one stream, so a larger ``n_random`` keeps the first schedules
    of a smaller one and adds more.
    """
    R = speed_limit(card)[0]
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
    # (docs/moments.md, Sec. 6); their schedules come from their own stream [seed, 4]. A card near the
    # limit of gamma or delta gets the factor cut there (plant_factors): Spec.factors is the plant's
    grng = np.random.default_rng([seed, 4])
    recipe = min(float(card.process.rpm), R)
    for g, d in (plant_factors(card, f) for f in TRAIN_FACTORS):
        specs.append(Spec(f"recipe-g{g:g}-d{d:g}", _grid([(HOURS, recipe, 1.0)]), factors=(g, d)))
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
    out = {"rpm": [float(lo), float(hi)],
           "temperature_c": [round(card.thermal.ambient_C, 2), round(steady_temperature_c(card, hi), 2)],
           "source": "milling speeds of the training experiments; vial temperatures from the ambient to the "
                     "steady temperature of the fastest (docs/moments.md, Sec. 9)"}
    capped = speed_limit(card)[1]
    if capped:
        out["speed_limit"] = capped
    return out


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
    top = speed_limit(card)[0]
    return [Spec(f"random-valid-{k}", random_schedule(rng, top)) for k in range(n)]


#: plant (gamma, delta) factors of the off-card check: the two +-30 % plants of the estimation study
FACTORS = ((1.3, 0.7), (0.7, 1.3))


def off_card_design(card: ModelCard) -> list[Spec]:
    """The off-card check: the card's own recipe (process rpm, 12 h) on plants whose gamma and
    delta are off the card (:data:`FACTORS`). Nothing is fitted on them: they test the derived
    response of the rates to the parameters p = (gamma, delta) factors (at most the top speed,
    :func:`speed_limit`). A factor that would take gamma or delta past its field's upper limit is cut
    there (:func:`plant_factors`)."""
    rpm = min(float(card.process.rpm), speed_limit(card)[0])
    return [Spec(f"recipe-g{g:g}-d{d:g}", _grid([(HOURS, rpm, 1.0)]), factors=(g, d))
            for g, d in (plant_factors(card, f) for f in FACTORS)]


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


class _Sensitivities:
    """The model's step with the free coefficients as inputs, and its forward sensitivities.

    ``step(x, u, p, theta) -> x_next`` is the model's step (:func:`bmctl.moments.equations.step`,
    the same expression :meth:`MomentModel.casadi_step` compiles) with ``theta`` symbolic, and
    ``sens(x, S, u, p, theta) -> (x_next, S_next)`` carries S = dx/dtheta along a trajectory:
    S_next = (d step / dx) S + d step / d theta, both exact (casadi SX Jacobians of the step). A
    trajectory of K intervals costs K evaluations of ``sens``; the Jacobian of every residual of an
    experiment follows from its S (one pass, not one per coefficient).
    """

    def __init__(self, model: MomentModel, free: Sequence[str], fixed: dict, dt_h: float, threads: int = 1):
        import casadi as ca

        from . import equations as eq

        self.free = list(free)
        nf = len(self.free)
        th = ca.SX.sym("theta", nf)
        q = dict(fixed)
        for i, k in enumerate(self.free):
            q[k] = th[i]
        _, rates = eq.casadi_rate_field(model.const, q, theta=th)
        x, u, p = ca.SX.sym("x", 6), ca.SX.sym("u", 2), ca.SX.sym("p", 2)
        n, s = model._integration(dt_h)
        xn = ca.vertcat(*eq.step(eq.CA(), model.const, q, [x[i] for i in range(6)], [u[0], u[1]], [p[0], p[1]],
                                 dt_h, n, s, rates=rates))
        S = ca.SX.sym("S", 6, nf)
        self.step = ca.Function("step_q", [x, u, p, th], [xn])
        # one Jacobian by (x, theta) together: its sweeps serve both blocks (half the instructions of two)
        J = ca.jacobian(xn, ca.vertcat(x, th))
        self.sens = ca.Function("sens_q", [x, S, u, p, th], [xn, ca.mtimes(J[:, :6], S) + J[:, 6:]])
        self._maps: dict = {}
        self.threads = threads

    def _batch(self, kind: str, K: int, n: int):
        """``step`` or ``sens`` accumulated over K intervals, mapped over n experiments on threads."""
        key = (kind, K, n)
        if key not in self._maps:
            f = self.step if kind == "step" else self.sens
            acc = f.mapaccum(f"{kind}_{K}", K, 1 if kind == "step" else 2)
            self._maps[key] = acc if n == 1 else acc.map(n, "thread", min(n, self.threads))
        return self._maps[key]

    def run(self, experiments: Sequence[Experiment], theta: np.ndarray, sensitivities: bool = False) -> list:
        """States (K, 6) of every experiment at ``theta``, with ``sensitivities`` also dx/dtheta (K, 6, n_free).

        Experiments of the same length run as one casadi map over threads (:attr:`threads`).
        """
        nf = len(self.free)
        out: list = [None] * len(experiments)
        groups: dict = {}
        for i, e in enumerate(experiments):
            groups.setdefault(e.U.shape[0], []).append(i)
        for K, ids in groups.items():
            n = len(ids)
            x0 = np.column_stack([experiments[i].x0 for i in ids])
            U = np.hstack([experiments[i].U.T for i in ids])
            P = np.hstack([np.tile(experiments[i].p[:, None], (1, K)) for i in ids])
            TH = np.tile(theta[:, None], (1, K * n))
            if sensitivities:
                X, S = self._batch("sens", K, n)(x0, np.zeros((6, nf * n)), U, P, TH)
                X = np.asarray(X).reshape(6, n, K).transpose(1, 2, 0)
                S = np.asarray(S).reshape(6, n, K, nf).transpose(1, 2, 0, 3)
                for j, i in enumerate(ids):
                    out[i] = (X[j], S[j])
            else:
                X = np.asarray(self._batch("step", K, n)(x0, U, P, TH)).reshape(6, n, K).transpose(1, 2, 0)
                for j, i in enumerate(ids):
                    out[i] = X[j]
        return out

    def simulate(self, e: Experiment, theta: np.ndarray) -> np.ndarray:
        """States after each interval of ``e`` (K, 6) at coefficients ``theta``."""
        return self.run([e], theta)[0]

    def with_sensitivities(self, e: Experiment, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """States (K, 6) and their derivatives by the free coefficients (K, 6, n_free)."""
        return self.run([e], theta, sensitivities=True)[0]


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
    njev: int = 0
    clipped: list = field(default_factory=list)  # coefficients ending at a bound
    start: str = ""
    tried: list = field(default_factory=list)


class _Budget(Exception):
    """The fit's Jacobian budget is spent."""


def fit(model: MomentModel, experiments: Sequence[Experiment], free: Sequence[str] = FREE,
        weights: Sequence[float] = (1.0, 1.0, 1.0, 1.0), max_nfev: int = 80,
        log: Callable[[str], None] | None = None, start: dict | None = None, ftol: float = 1e-8,
        on_step: Callable[[dict, float], None] | None = None, threads: int | None = None,
        starts: Sequence[tuple[str, dict]] | None = None, max_jacobians: int | None = None) -> FitResult:
    """Least-squares fit of ``free`` coefficients on range-normalised simulation errors (:func:`run_scales`).

    Levenberg-Marquardt (MINPACK) with exact Jacobians (:class:`_Sensitivities`); from each of
    ``starts`` (or ``start``), keeping the result of lowest cost.

    Parameters
    ----------
    model : MomentModel
        Supplies the card's constants and the fixed coefficients (those not in ``free``).
    experiments : sequence of Experiment
        The training data (one interval length).
    free : sequence of str
        Coefficients to fit.
    weights : sequence of float, optional
        Residual weights of s_mean, s_std, r_mean, r_std.
    max_nfev : int, optional
        Most residual evaluations per start.
    log : callable, optional
        Progress lines (one per Jacobian).
    start : dict, optional
        Starting values of the free coefficients (default: the model's).
    ftol : float, optional
        Relative change of the cost at which a fit stops.
    on_step : callable, optional
        Called with (coefficients, cost) at every accepted point (each Jacobian).
    threads : int, optional
        Threads of the casadi maps that run the experiments (default: the usable CPUs). Same result
        for any number.
    starts : sequence of (label, dict), optional
        Several starting points (each a partial coefficient table over the model's); overrides ``start``.
    max_jacobians : int, optional
        Most Jacobians per pass: a fit that has not converged by then keeps its lowest-cost point. A start
        whose fit leaves a coefficient's bounds continues in a second, bounded pass with a budget of its
        own (so at most twice this many per start).

    Returns
    -------
    FitResult
    """
    from scipy.optimize import least_squares

    t0 = time.time()
    if threads is None:
        from ..parallel import default_workers

        threads = default_workers()
    fixed = {k: v for k, v in model.coeffs.items() if k not in free}
    dts = {round(e.dt_h, 12) for e in experiments}
    if len(dts) != 1:
        raise ValueError(f"fit: experiments of one interval length expected (got {sorted(dts)})")
    sens = _Sensitivities(model, free, fixed, experiments[0].dt_h, threads=threads)
    sc = run_scales(experiments)
    w = np.ones(6)
    w[list(FIT_IDX)] = weights
    idx = list(FIT_IDX)
    scale = [(w[idx] / sce[idx])[None, :] for sce in sc]  # per experiment, (1, 4)
    lo = np.array([cf.SPEC[k][1] for k in free])
    hi = np.array([cf.SPEC[k][2] for k in free])
    count = [0, 0]
    costs: dict = {}

    # Levenberg-Marquardt (MINPACK), first unbounded in the coefficients themselves (a bounded trust region,
    # trf, stalled at several times the cost); if that leaves a coefficient's bounds, it continues from the
    # point pulled back inside, bounded through theta = lo + (hi - lo) sigmoid(z) (clipping alone undid the fit)
    span_ = hi - lo

    def sig(z):
        return 1.0 / (1.0 + np.exp(-np.clip(z, -40.0, 40.0)))

    mode = ["plain"]

    def theta(v):
        return v if mode[0] == "plain" else lo + span_ * sig(v)

    def dtheta(v):
        return np.ones_like(v) if mode[0] == "plain" else span_ * sig(v) * (1.0 - sig(v))

    def fun(v):
        th = theta(v)
        count[0] += 1
        parts = [((X[:, idx] - e.Y[1:, idx]) * scl).T.ravel()
                 for X, e, scl in zip(sens.run(experiments, th), experiments, scale)]
        r = np.concatenate(parts)
        r = np.where(np.isfinite(r), r, 1e3)
        costs[v.tobytes()] = (0.5 * float(r @ r), np.array(v))
        return r

    def lm(v0, st, tag, budget):
        """(coefficients, message, Jacobians) of one Levenberg-Marquardt run in the current mode."""
        costs.clear()
        njev = [0]

        def jac(v):
            if budget is not None and njev[0] >= budget:
                raise _Budget()
            njev[0] += 1
            count[1] += 1
            th = theta(v)
            rows = [(S[:, idx, :] * scl[:, :, None]).transpose(1, 0, 2).reshape(-1, len(free))
                    for (_, S), scl in zip(sens.run(experiments, th, sensitivities=True), scale)]
            Jv = np.concatenate(rows) * dtheta(v)[None, :]
            cost = costs.get(v.tobytes(), (float("nan"),))[0]
            if log:
                log(f"{tag}: step {njev[0]}, cost {cost:.4g} ({time.time() - t0:.1f} s)")
            if on_step is not None:
                on_step(dict(st, **{k: float(x) for k, x in zip(free, th)}), cost)
            return np.where(np.isfinite(Jv), Jv, 0.0)

        fun(v0)
        try:
            sol = least_squares(fun, v0, jac=jac, method="lm", x_scale="jac", max_nfev=max_nfev, ftol=ftol,
                                xtol=1e-10)
            v, message = sol.x, str(sol.message)
        except _Budget:
            v = min(costs.values(), key=lambda cv: cv[0])[1]
            message = f"stopped after {budget} Jacobians at the lowest cost seen"
        return theta(v), message, njev[0]

    runs = []
    todo = list(starts or [("", start or {})])
    for n_start, (label, st) in enumerate(todo, 1):
        tag = f"fit, start {n_start}/{len(todo)}" if len(todo) > 1 else "fit"
        st = dict(model.coeffs, **st)
        th0 = np.clip(np.array([st[k] for k in free]), lo, hi)
        mode[0] = "plain"
        r0 = fun(th0)
        cost0 = 0.5 * float(r0 @ r0)
        if log:
            log(f"{tag}: {len(free)} coefficients, {r0.size} residuals, initial cost {cost0:.4g}"
                + (f" ({label})" if label else "") + f" ({time.time() - t0:.1f} s)")
        n0 = count[0]
        x, message, nj = lm(th0, st, tag, max_jacobians)
        outside = [k for k, v, a, b in zip(free, x, lo, hi) if not a <= v <= b]
        if outside:
            if log:
                log(f"{tag}: {', '.join(outside)} left the bounds; continuing bounded from the point pulled inside")
            u = np.clip((x - lo) / span_, 1e-3, 1 - 1e-3)
            mode[0] = "bounded"
            x, message, nj2 = lm(np.log(u / (1 - u)), st, tag, max_jacobians)
            nj += nj2
        at_bound = [k for k, v, a, b in zip(free, x, lo, hi) if min(v - a, b - v) < 1e-3 * (b - a)]
        mode[0] = "plain"
        r = fun(np.clip(x, lo, hi))
        runs.append({"label": label, "x": np.clip(x, lo, hi), "cost0": cost0, "cost": 0.5 * float(r @ r),
                     "nfev": count[0] - n0, "njev": nj, "message": message, "clipped": at_bound, "start": st})
    best = min(runs, key=lambda rr: rr["cost"])
    out = dict(best["start"])
    out.update({k: float(v) for k, v in zip(free, best["x"])})
    if log:
        tried = "; ".join(f"start {i}: {rr['cost0']:.4g} -> {rr['cost']:.4g}" for i, rr in enumerate(runs, 1))
        log(f"fit: cost {tried}; kept start {runs.index(best) + 1} ({count[1]} Jacobians, {time.time() - t0:.1f} s)")
    return FitResult(out, best["cost0"], best["cost"], int(count[0]), time.time() - t0, best["message"], count[1],
                     best["clipped"], best["label"],
                     [{"start": rr["label"], "cost_initial": round(rr["cost0"], 6), "cost_final": round(rr["cost"], 6),
                       "jacobians": rr["njev"]} for rr in runs])


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


#: training plant seeds (offsets to 1000 x --seed) of the default identification; ``--seeds 4`` is the
#: shipped cards' setting (TRAIN_SEEDS)
DEFAULT_SEEDS = 2
#: held-out random schedules of the default identification (each on VALID_SEEDS); N_VALID the shipped cards'
DEFAULT_HELDOUT = 24
#: most residual evaluations of the fit per start (Levenberg-Marquardt rejects some trial steps)
DEFAULT_EVALUATIONS = 40
#: most Jacobians per start: the fits level off within 6-8 (docs/moments.md, Sec. 6)
DEFAULT_JACOBIANS = 8


def warm_start(card: ModelCard, candidates: Sequence) -> tuple[dict, str]:
    """Starting coefficients for a fit of ``card``: those of the nearest identified card, else the defaults.

    The nearest is the candidate whose recorded fingerprint values (``[card.values]``) are closest to
    the card's (sum over the shared fields of |ln(a/b)|, or |a - b| / max(|a|, |b|) where a sign
    differs or a value is 0). Its coefficients carry over as they are, except the four derived threshold
    laws, whose identified *corrections* carry over: start = derived law of ``card`` + (identified -
    derived law of the candidate's alpha, beta and threshold sharpness).

    Parameters
    ----------
    card : ModelCard
        The card to identify.
    candidates : sequence of CoeffFile
        Identified coefficient files (those without a fingerprint are skipped).

    Returns
    -------
    (dict, str)
        All coefficients (defaults where a candidate has none) and where they came from.
    """
    import math

    from ..cards import fingerprint_values
    from .model import default_coeffs

    base = default_coeffs(card)
    mine = fingerprint_values(card)

    def dist(values: dict) -> float:
        d = 0.0
        for k, a in mine.items():
            b = values.get(k)
            if b is None:
                d += 1.0
            elif a > 0 and b > 0:
                d += abs(math.log(a / b))
            elif a != b:
                d += abs(a - b) / max(abs(a), abs(b))
        return d

    usable = [c for c in candidates if c.values]
    if not usable:
        return base, "the built-in defaults (no identified card to start from)"
    near = min(usable, key=lambda c: (dist(c.values), str(c.path)))
    v = near.values
    other = card.model_copy(update={
        "stochastic": card.stochastic.model_copy(update={"alpha": float(v.get("stochastic.alpha", card.stochastic.alpha)),
                                                         "beta": float(v.get("stochastic.beta", card.stochastic.beta))}),
        "partition": card.partition.model_copy(update={"threshold_sharpness": float(v.get(
            "partition.threshold_sharpness", card.partition.threshold_sharpness))})})
    their = default_coeffs(other)
    out = dict(base)
    for k, val in near.coeffs.items():
        out[k] = base[k] + (val - their[k]) if cf.SPEC[k][0] is None else val
        lo, hi = cf.SPEC[k][1], cf.SPEC[k][2]
        out[k] = min(max(out[k], lo), hi)
    from .forcard import is_shipped

    where = f"models/{near.path.name}" if is_shipped(near.path) else str(near.path)
    return out, f"{where} (card {near.card_name}, the nearest identified card)"


def identified_candidates(*folders) -> list:
    """Coefficient files with a card fingerprint in ``folders`` (default: the shipped ``models/``).

    Parameters
    ----------
    *folders : path-like
        Folders to look in (unreadable files are skipped).
    """
    from pathlib import Path

    from ..errors import InputError
    from .forcard import SHIPPED_DIR

    out, seen = [], set()
    for folder in list(folders) + [SHIPPED_DIR]:
        folder = Path(folder)
        for p in sorted(folder.glob("*.moments.toml")) if folder.is_dir() else []:
            key = p.resolve()
            if key in seen:
                continue
            seen.add(key)
            try:
                f = cf.read_file(p)
            except (InputError, OSError):
                continue
            if f.values:
                out.append(f)
    return out


class _Progress:
    """Prints "plant experiments: k/N runs" about every tenth of the way."""

    def __init__(self, log, total: int):
        self.log, self.total, self.done, self.next = log, total, 0, 0

    def __call__(self, _line: str = "") -> None:
        self.done += 1
        if self.done >= self.next or self.done == self.total:
            self.log(f"plant experiments: {self.done}/{self.total} runs")
            self.next = self.done + max(1, self.total // 10)


def identify(card: ModelCard, seed: int = 0, quick: bool = False, particles: int | None = None,
             random_schedules: int | None = None, source: str = "", command: str = "",
             log: Callable[[str], None] | None = None, client=None, seeds: int | None = None,
             heldout: int | None = None, start: dict | None = None, start_label: str = "",
             evaluations: int | None = None, threads: int | None = None, jacobians: int | None = None,
             both_starts: bool = True, warn: Callable[[str], None] | None = None) -> Identification:
    """Fit the moment model of ``card`` to a design of plant experiments and validate it.

    Three phases, each reporting through ``log``: the plant experiments (training, held-out and
    off-card runs), the fit (one line per step), the validation (held-out NRMSE per output).

    Parameters
    ----------
    card : ModelCard
        The model card.
    seed : int, optional
        Seed of the plant ensembles and the design (seeds are offsets to 1000 x seed).
    quick : bool, optional
        Fewer experiments and held-out schedules, one training seed, M = 2000.
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
    seeds : int, optional
        Training plant seeds (default :data:`DEFAULT_SEEDS`; quick 1).
    heldout : int, optional
        Held-out random schedules (default :data:`DEFAULT_HELDOUT`; quick 4), each on the three
        seeds :data:`VALID_SEEDS` (quick: two).
    start : dict, optional
        Starting coefficients of the fit (:func:`warm_start`); the fit runs from them and, with
        ``both_starts``, from the built-in defaults, and keeps the lower cost. None: the defaults only.
    start_label : str, optional
        Where ``start`` came from (recorded).
    evaluations : int, optional
        Most residual evaluations of the fit per start (default :data:`DEFAULT_EVALUATIONS`).
    jacobians : int, optional
        Most Jacobians per start (default :data:`DEFAULT_JACOBIANS`).
    both_starts : bool, optional
        Also fit from the built-in defaults when ``start`` is given (default True).
    threads : int, optional
        Threads of the fit (default: the usable CPUs; same result for any number).
    warn : callable, optional
        Called with the one-line warning of :func:`speed_limit` when the experiments stop below the
        mill's rpm_max (default: ``log``).
    """
    from datetime import datetime, timezone

    from .model import default_coeffs

    log = log or (lambda msg: None)
    capped = speed_limit(card)[1]
    if capped:
        (warn or log)(capped)
    particles = particles or default_particles(quick)
    n_seeds = seeds if seeds is not None else (1 if quick else DEFAULT_SEEDS)
    n_held = heldout if heldout is not None else (4 if quick else DEFAULT_HELDOUT)
    train_seeds, valid_seeds = plant_seeds(seed, n_seeds, quick)
    specs = design(card, seed, quick, random_schedules)
    vspecs = validation_design(card, seed, n_held)
    ospecs = off_card_design(card)
    n_runs = len(specs) * len(train_seeds) + (len(vspecs) + len(ospecs)) * len(valid_seeds)
    log(f"{card.card.name}: plant experiments: {len(specs)} training x {len(train_seeds)} seeds, {len(vspecs)} "
        f"held-out and {len(ospecs)} off-card x {len(valid_seeds)} seeds, M={particles} ({n_runs} runs)")
    prog = _Progress(log, n_runs)
    t_plant = time.time()
    train = run_experiments(card, specs, train_seeds, particles, progress=prog, client=client)
    valid = run_experiments(card, vspecs, valid_seeds, particles, progress=prog, client=client)
    off = run_experiments(card, ospecs, valid_seeds, particles, progress=prog, client=client)
    t_plant = time.time() - t_plant

    defaults = default_coeffs(card)
    model0 = MomentModel(card, defaults, "defaults")
    starts = [(start_label or "the given coefficients", start)] if start else []
    if start is None or both_starts:
        starts.append(("the built-in defaults", {}))
    log(f"fit: {len(FREE)} coefficients; " + "; ".join(f"start {i}: {lab}" for i, (lab, _) in enumerate(starts, 1)))
    res = fit(model0, train, log=log, starts=starts, max_nfev=evaluations or DEFAULT_EVALUATIONS, ftol=1e-3,
              threads=threads, max_jacobians=jacobians or DEFAULT_JACOBIANS)
    model = MomentModel(card, res.coeffs, source)
    check_finite(source, train + valid + off, res.coeffs)
    log(f"validation: {len(valid)} held-out schedules, {len(off)} off-card runs")
    tab0, tab, tab_train = nrmse_table(model0, valid), nrmse_table(model, valid), nrmse_table(model, train)
    # off-card check: the model told the plant's (gamma, delta) factors, and not told (p = 1)
    otab = nrmse_table(model, off)
    otab1 = nrmse_table(model, [replace(e, p=np.ones(2)) for e in off])
    log("validation: held-out NRMSE " + ", ".join(f"{k.removesuffix('_um')} {100 * v:.1f} %"
                                                    for k, v in zip(MOMENTS[:4], tab["mean"][:4])))

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
        "dt_h": DT_H, "start": res.start,
        "starts": [f"{t['start']}: cost {t['cost_initial']:.6g} -> {t['cost_final']:.6g} in {t['jacobians']} Jacobians"
                   for t in res.tried], "cost_initial": round(res.cost0, 6),
        "cost_final": round(res.cost, 6), "evaluations": res.nfev, "jacobians": res.njev,
        "at_bound": list(res.clipped),
        "plant_seconds": round(t_plant, 1), "fit_seconds": round(res.seconds, 1),
    }
    sections = {"card": card_table(card), "window": design_window(card, specs), "identification": meta,
                "validation": validation}
    text = cf.toml_text(res.coeffs, sections,
                        header=f"Moment-model coefficients of {card.card.name}, written by `bmctl identify`.\n"
                               "Re-run the command in [identification] to regenerate; docs/moments.md explains them.")
    return Identification(card.card.name, res.coeffs, res, valid, tab, tab0, tab_train, otab, otab1, validation,
                          meta, text)
