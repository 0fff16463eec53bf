"""Fit named card parameters to measured histories with the stochastic plant as the simulator.

Method (docs/calibration-from-data.md): Gaussian synthetic likelihood of per-sample
summaries (Wood 2010), maximised by Gauss-Newton / Levenberg-Marquardt steps whose
Jacobian comes from central differences of plant runs under common random numbers
(the method of simulated moments, McFadden 1989), with a weak log-normal prior centred
on the card. The estimate and the 90 % intervals come from the posterior scanned along its
least-informed direction (:func:`ridge_posterior`; with ``ridge_scan`` off, from the Laplace
approximation, the inverse of J'WJ + prior precision); the Fisher information J'WJ says which
parameters the data identify.

Parameters are fitted as u = ln(value / card value).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated, Callable, Literal, Sequence

import numpy as np
from pydantic import Field

from ..config import ModelCard, Strict
from ..parallel import map_seeded
from .history import History
from .params import get_params, param_bounds
from .simulate import SimTask, bootstrap_cov, simulate_task, summaries

Z90 = 1.6448536269514722  # two-sided 90 %: Phi^-1(0.95)


class FitSettings(Strict):
    """Settings of :func:`calibrate`."""

    particles: Annotated[int, Field(ge=100)] = 2000  # simulated particles per plant run
    replicates: Annotated[int, Field(ge=2)] = 2  # common-random-number seeds per design point
    fd_step: Annotated[float, Field(gt=0, le=1)] = 0.3  # central-difference step in ln(value)
    max_iter: Annotated[int, Field(ge=1)] = 8
    prior_sd: Annotated[float, Field(gt=0)] = 1.0  # sd of ln(value / card value) in the prior
    bootstrap: Annotated[int, Field(ge=50)] = 400  # resamples for the data's summary covariance
    tol: Annotated[float, Field(gt=0)] = 0.5  # stop when a step is below this many posterior sd (the objective is noisy below)
    max_step: Annotated[float, Field(gt=0)] = 0.7  # largest change of ln(value) in one step
    unidentified_ratio: Annotated[float, Field(gt=0, lt=1)] = 0.5  # posterior sd / prior sd above this: not identified
    #: after the Gauss-Newton steps, scan the posterior along its least-informed direction (the ridge)
    #: and take the estimate and the 90 % intervals from that scan instead of the Laplace approximation
    ridge_scan: bool = True
    ridge_step_sd: Annotated[float, Field(gt=0, le=2)] = 1.0  # grid step along the ridge, in Laplace sd
    ridge_max_sd: Annotated[float, Field(gt=0, le=20)] = 6.0  # farthest grid point, in Laplace sd
    ridge_tail: Annotated[float, Field(gt=0)] = 4.5  # extend the grid while an end is within this of the best -2 ln L
    #: how the fit's plant runs draw (5), (9): "card" (its [simulation] samplers), or "exact" /
    #: "tabulated" whatever the card says; the laws, and so the estimate's meaning, are the same
    samplers: Literal["card", "exact", "tabulated"] = "card"


@dataclass
class Calibration:
    """Result of :func:`calibrate` (values in the card's units)."""

    names: list[str]
    card_values: np.ndarray
    start_values: np.ndarray
    values: np.ndarray
    lo90: np.ndarray
    hi90: np.ndarray
    u: np.ndarray  # ln(value / card value)
    cov_u: np.ndarray
    prior_sd: float
    chi2: float  # r'Wr at the last evaluated point
    n_summaries: int
    fisher: np.ndarray  # J'WJ in u
    identified: list[bool]
    why: list[str]
    converged: bool
    plant_runs: int
    iterations: list[dict] = field(default_factory=list)
    stop_reason: str = ""  # why the Gauss-Newton steps stopped, and (when not converged) what would help
    start_choice: dict = field(default_factory=dict)
    ridge: dict = field(default_factory=dict)  # the scan along the least-informed direction (empty: Laplace)
    sim_var: np.ndarray | None = None
    obs_cov: np.ndarray | None = None


def observed(histories: Sequence[History], rng: np.random.Generator, n_boot: int) -> tuple[np.ndarray, np.ndarray]:
    """Stacked measured summaries y and their block-diagonal sampling covariance."""
    y, blocks = [], []
    for h in histories:
        for smp in h.samples:
            y.append(summaries(smp.s_um, smp.r))
            blocks.append(bootstrap_cov(smp.s_um, smp.r, rng, n_boot))
    n = 4 * len(blocks)
    cov = np.zeros((n, n))
    for k, b in enumerate(blocks):
        cov[4 * k:4 * k + 4, 4 * k:4 * k + 4] = b
    return np.concatenate(y), cov


def _design(u: np.ndarray, h: float) -> np.ndarray:
    """Centre, then u + h e_i and u - h e_i for each i: (2p + 1, p)."""
    p = u.size
    pts = [u.copy()]
    for i in range(p):
        for sgn in (1.0, -1.0):
            v = u.copy()
            v[i] += sgn * h
            pts.append(v)
    return np.array(pts)


class _Evaluator:
    """Plant runs of the design points, common random numbers across points."""

    def __init__(self, card: ModelCard, names, histories, settings: FitSettings, seeds, client, progress):
        self.card_dict = card.model_dump()
        if settings.samplers != "card":
            self.card_dict["simulation"]["samplers"] = settings.samplers
        self.card_values = np.array(get_params(card, names))
        # the card's range of each constant: a trial value beyond it is run at the bound, never refused
        self.lo, self.hi = np.array([param_bounds(card, n) for n in names]).T
        self.names = list(names)
        self.histories = histories
        self.s = settings
        self.seeds = seeds  # [history][replicate] SeedSequence
        self.client = client
        self.progress = progress
        self.runs = 0

    def task(self, u: np.ndarray, hist: History, keep: int = 0) -> SimTask:
        vals = tuple((n, float(v)) for n, v in zip(self.names, self.values(u)))
        return SimTask(self.card_dict, vals, tuple(hist.segments), tuple(hist.times_h), self.s.particles, keep)

    def values(self, u: np.ndarray) -> np.ndarray:
        """Card values at u = ln(value / card value), kept within the card's range of each."""
        return np.clip(self.card_values * np.exp(u), self.lo, self.hi)

    def run(self, points: np.ndarray) -> np.ndarray:
        """Summaries (points, replicates, n_summaries)."""
        R = self.s.replicates
        tasks, seeds = [], []
        for u in points:
            for r in range(R):
                for hi, hist in enumerate(self.histories):
                    tasks.append(self.task(u, hist))
                    seeds.append(self.seeds[hi][r])
        out = map_seeded(simulate_task, tasks, seeds, self.client, self.progress)
        self.runs += len(tasks)
        S = [o[0].ravel() for o in out]
        nh = len(self.histories)
        rows = [np.concatenate(S[k:k + nh]) for k in range(0, len(S), nh)]
        return np.array(rows).reshape(len(points), R, -1)


def _jacobian_information(S: np.ndarray, W: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Central-difference Jacobian and its Fisher information J'WJ, debiased for simulation noise.

    ``S``: summaries (2p + 1 points, R replicates, n). Each replicate r gives its own Jacobian J_r
    (common random numbers within a replicate); J is their mean. Noise in J inflates J'WJ by
    E[dJ' W dJ], estimated from the spread of the J_r and subtracted; the result is projected
    onto the positive semi-definite matrices. Without this, a parameter the summaries ignore
    would look identified by its finite-difference noise alone.
    """
    p = (S.shape[0] - 1) // 2
    R = S.shape[1]
    Jr = np.stack([(S[1 + 2 * i] - S[2 + 2 * i]) / (2 * h) for i in range(p)], axis=2)  # (R, n, p)
    J = Jr.mean(axis=0)
    D = Jr - J
    noise = np.einsum("rki,kl,rlj->ij", D, W, D) / (R * (R - 1))
    F = J.T @ W @ J - noise
    lam, vec = np.linalg.eigh(0.5 * (F + F.T))
    F = (vec * np.maximum(lam, 0.0)) @ vec.T
    return J, F


def _weight(obs_cov: np.ndarray, sim_var: np.ndarray, R: int) -> np.ndarray:
    C = obs_cov + np.diag(sim_var / R)
    C = C + np.diag(1e-12 + 1e-9 * np.diag(C))
    return np.linalg.inv(C)


def _setup(card: ModelCard, names, histories, s: FitSettings, seed: int, client, progress):
    """The measured summaries ``y``, their covariance, and the plant evaluator with common random
    numbers: one SeedSequence(seed) split into the bootstrap's stream and one per history and replicate."""
    boot_ss, sim_ss = np.random.SeedSequence(seed).spawn(2)
    y, obs_cov = observed(histories, np.random.default_rng(boot_ss), s.bootstrap)
    crn = sim_ss.spawn(len(histories) * s.replicates)
    seeds = [[crn[hi * s.replicates + r] for r in range(s.replicates)] for hi in range(len(histories))]
    return y, obs_cov, _Evaluator(card, names, histories, s, seeds, client, progress)


def calibrate(card: ModelCard, histories: Sequence[History], names: Sequence[str], seed: int = 0,
              settings: FitSettings | None = None, start_u: np.ndarray | None = None, client=None,
              progress: Callable[[int], None] | None = None,
              on_iteration: Callable[[dict], None] | None = None) -> Calibration:
    """Fit the named card parameters to the histories' measured samples.

    Parameters
    ----------
    card : ModelCard
        The starting card (also the prior centre and the mill).
    histories : sequence of History
        Measured runs of the same powder.
    names : sequence of str
        Parameter names (see :mod:`bmctl.calibrate.params`).
    seed : int, optional
        Seed of every random draw (plant runs, bootstrap).
    settings : FitSettings, optional
    start_u : ndarray, optional
        Starting ln(value / card value) (e.g. from the moment model); default 0 (the card).
    client : distributed.Client, optional
        Dask client (None: serial).
    progress : callable, optional
        Called with 1 after each plant run.
    on_iteration : callable, optional
        Called with each iteration's log entry.

    Returns
    -------
    Calibration
    """
    s = settings or FitSettings()
    names = list(names)
    p = len(names)
    y, obs_cov, ev = _setup(card, names, histories, s, seed, client, progress)
    P = np.eye(p) / s.prior_sd**2
    u = np.zeros(p)
    start_choice = {"start": "card"}
    if start_u is not None and np.any(np.asarray(start_u) != 0):
        cand = np.clip(np.asarray(start_u, float), -3 * s.prior_sd, 3 * s.prior_sd)
        S0 = ev.run(np.array([u, cand])).mean(axis=1)  # card vs first-stage start, data covariance only
        W0 = np.linalg.inv(obs_cov + np.diag(1e-12 + 1e-9 * np.diag(obs_cov)))
        q = [float((y - m) @ W0 @ (y - m)) for m in S0]
        start_choice = {"start": "first stage" if q[1] < q[0] else "card", "chi2_card": q[0], "chi2_first_stage": q[1]}
        if q[1] < q[0]:
            u = cand
    u_start = u.copy()
    sim_vars: list[np.ndarray] = []
    prev = None  # (u, residual, delta) of the last accepted centre
    halvings = 0
    log: list[dict] = []
    converged = False
    H = F = None
    J_last = W_last = H_last = None
    chi2 = float("nan")
    delta = np.zeros(p)
    for it in range(s.max_iter):
        pts = _design(u, s.fd_step)
        S = ev.run(pts)
        sim_vars.append(S.var(axis=1, ddof=1).mean(axis=0))
        sim_var = np.mean(sim_vars, axis=0)
        W = _weight(obs_cov, sim_var, s.replicates)
        mu = S.mean(axis=1)
        res = y - mu[0]
        chi2 = float(res @ W @ res)
        Q = chi2 + float(u @ P @ u)
        entry = {"iteration": it, "values": ev.values(u).tolist(), "chi2": chi2, "objective": Q}
        if prev is not None:
            Q_prev = float(prev[1] @ W @ prev[1] + prev[0] @ P @ prev[0])
            entry["objective_previous"] = Q_prev
            if Q > Q_prev and halvings < 2:
                halvings += 1
                u = prev[0] + prev[2] * 0.5**halvings
                entry["action"] = "worse: step halved"
                log.append(entry)
                if on_iteration:
                    on_iteration(entry)
                continue
        halvings = 0
        J, F = _jacobian_information(S, W, s.fd_step)
        H = F + P
        J_last, W_last, H_last = J, W, H
        g = J.T @ W @ res - P @ u
        delta = np.linalg.solve(H, g)
        big = np.max(np.abs(delta))
        if big > s.max_step:
            delta *= s.max_step / big
        size = float(np.sqrt(delta @ H @ delta))
        entry.update(step_in_sd=size, action="step")
        log.append(entry)
        if on_iteration:
            on_iteration(entry)
        prev = (u.copy(), res, delta.copy())
        if size < s.tol:
            converged = True
            break
        u = u + delta
    stop_reason = _stop_reason(log, converged, s, chi2, y.size)
    u_hat = (prev[0] + prev[2]) if prev is not None else u
    cov = np.linalg.inv(H)
    sd = np.sqrt(np.diag(cov))
    lo, hi = u_hat - Z90 * sd, u_hat + Z90 * sd
    ridge: dict = {}
    if s.ridge_scan and J_last is not None:
        u_hat, lo, hi, cov, ridge = ridge_posterior(ev, y, W_last, P, J_last, H_last, u_hat, s)
        chi2 = ridge["chi2_at_estimate"]
        sd = np.sqrt(np.diag(cov))
    ratio = sd / s.prior_sd
    identified, why = _identifiability(names, F, ratio, s, bounds_hit(ev, u_hat))
    cv = ev.card_values
    return Calibration(
        names=names, card_values=cv, start_values=ev.values(u_start), values=ev.values(u_hat),
        lo90=ev.values(lo), hi90=ev.values(hi), u=u_hat, cov_u=cov,
        prior_sd=s.prior_sd, chi2=chi2, n_summaries=y.size, fisher=F, identified=identified, why=why,
        converged=converged, plant_runs=ev.runs, iterations=log, sim_var=sim_var, obs_cov=obs_cov,
        start_choice=start_choice, ridge=ridge, stop_reason=stop_reason,
    )


def _stop_reason(log: list[dict], converged: bool, s: FitSettings, chi2: float, n: int) -> str:
    """One line: why the Gauss-Newton steps stopped and, when they did not converge, what would help."""
    steps = [e["step_in_sd"] for e in log if "step_in_sd" in e]
    if converged:
        return f"converged: step {steps[-1]:.2f} posterior sd < {s.tol:g} after {len(log)} iterations"
    last = f"{steps[-1]:.2f}" if steps else "n/a"
    halved = sum(1 for e in log[-3:] if e.get("action", "").startswith("worse"))
    if n and chi2 > 3.0 * n:
        helps = (f"the model does not reach the data (chi2 {chi2:.0f} on {n} summaries at the last Gauss-Newton "
                 "step): check the card's "
                 "fixed parameters or fit more of them")
    elif halved:
        helps = ("the objective is noisy at this scale (steps were halved): more simulated particles "
                 "(--particles) or replicates (--replicates)")
    elif len(steps) >= 2 and steps[-1] < steps[-2]:
        helps = "the steps were still shrinking: more iterations (FitSettings.max_iter) would likely converge"
    else:
        helps = ("the data constrain the parameters weakly along a ridge: more or larger samples, or samples at "
                 "another time or rpm")
    return (f"not converged: iteration cap {s.max_iter} reached with a last step of {last} posterior sd "
            f"(tolerance {s.tol:g}); {helps}")


def ridge_posterior(ev: _Evaluator, y: np.ndarray, W: np.ndarray, P: np.ndarray, J: np.ndarray, H: np.ndarray,
                    u0: np.ndarray, s: FitSettings):
    """Estimate and 90 % intervals from the posterior scanned along its least-informed direction.

    The synthetic likelihood of few samples is often a curved, nearly flat ridge (γ against δ:
    bonding against fracture) along which the Gauss-Newton steps stop anywhere and a Laplace
    interval at the stopping point does not reach back along the ridge. Here the weakest
    eigenvector v of the Laplace precision ``H`` is scanned: plant runs (same common random
    numbers) at u0 + τ v on a grid of ``ridge_step_sd`` Laplace sd, extended at either end while
    the end's -2 ln posterior is within ``ridge_tail`` of the best, up to ``ridge_max_sd`` (and
    3 prior sd). At each grid point the other directions are re-fitted by one Gauss-Newton step
    with the Jacobian ``J`` (their conditional posterior is Gaussian with precision ``H`` restricted
    to them), which gives the profile -2 ln posterior q(τ) and the conditional means. The
    posterior is then the mixture over the grid with weights exp(-q/2) (integration over one
    direction, as INLA integrates over its hyperparameters): the estimate is its median, the 90 %
    interval its 5 % and 95 % quantiles per parameter, the covariance the mixture's. The ridge is
    far from a parabola (a steep wall on one side, a long slope on the other), which the mixture
    follows and a Laplace approximation does not.

    Parameters
    ----------
    ev : _Evaluator
        Plant runs of points in u (``ev.run(points)`` -> summaries (points, replicates, n)).
    y : ndarray
        Measured summaries.
    W : ndarray
        Weight (inverse covariance of the summaries) of the last Gauss-Newton iteration.
    P : ndarray
        Prior precision in u.
    J : ndarray
        Jacobian of the summaries in u (last iteration).
    H : ndarray
        Laplace precision J'WJ + P.
    u0 : ndarray
        Where the Gauss-Newton steps ended (the scan's centre).
    s : FitSettings
        ``ridge_step_sd``, ``ridge_max_sd``, ``ridge_tail``, ``prior_sd``.

    Returns
    -------
    u_hat, lo, hi, cov, info
        ln(value / card value) estimate, 90 % bounds and covariance; ``info`` for calibration.json.
    """
    p = u0.size
    lam, vec = np.linalg.eigh(0.5 * (H + H.T))
    v = vec[:, 0]
    sd_v = 1.0 / np.sqrt(lam[0])
    Wb = vec[:, 1:]  # the better-informed directions
    Cw = np.linalg.inv(Wb.T @ H @ Wb) if p > 1 else np.zeros((0, 0))
    C_other = Wb @ Cw @ Wb.T  # their conditional covariance in u ((p, p); zero for one parameter)
    lim = min(s.ridge_max_sd * sd_v, 3.0 * s.prior_sd / max(np.max(np.abs(v)), 1e-12))
    step = min(s.ridge_step_sd * sd_v, lim / 2.0)  # at least -2..2 inside the limits (a prior-wide ridge)
    grid: dict[int, tuple[float, np.ndarray, np.ndarray]] = {}  # k -> (q, conditional mean point u, chi2)

    def evaluate(ks):
        ks = [k for k in ks if k not in grid and abs(k * step) <= lim + 1e-12]
        if not ks:
            return False
        pts = np.array([u0 + k * step * v for k in ks])
        mu = ev.run(pts).mean(axis=1)
        for k, u, m in zip(ks, pts, mu):
            r = y - m
            chi2 = float(r @ W @ r)
            q = chi2 + float(u @ P @ u)
            if p > 1:  # one Gauss-Newton step in the other directions: profile value and conditional mean
                g = Wb.T @ (J.T @ W @ r - P @ u)
                c = Cw @ g
                drop = float(g @ c)
                # a step predicted to take q below zero (q is a sum of squares) is one J does not describe
                # here (far from where J was taken, or H's debiased information below J'WJ): the point
                # keeps its own exact value instead of a negative profile that would take all the weight
                if drop <= q:
                    q -= drop
                    u = u + Wb @ c
            grid[k] = (q, u, chi2)
        return True

    n0 = int(np.ceil(2.0 / s.ridge_step_sd))
    evaluate(list(range(-n0, n0 + 1)))
    while True:
        ks = sorted(grid)
        best = min(grid[k][0] for k in ks)
        ext = []
        if grid[ks[0]][0] - best < s.ridge_tail:
            ext.append(ks[0] - 1)
        if grid[ks[-1]][0] - best < s.ridge_tail:
            ext.append(ks[-1] + 1)
        if not evaluate(ext):
            break
    ks = sorted(grid)
    q = np.array([grid[k][0] for k in ks])
    centres = np.array([grid[k][1] for k in ks])
    wts = np.exp(-0.5 * (q - q.min()))
    wts /= wts.sum()
    # within a grid cell the ridge coordinate is spread uniformly over one step
    var_in = np.outer(v, v) * step**2 / 12.0 + C_other
    sd_in = np.sqrt(np.maximum(np.diag(var_in), 1e-30))
    mean = wts @ centres
    cov = (centres - mean).T @ ((centres - mean) * wts[:, None]) + var_in
    qs = np.array([_mixture_quantiles(centres[:, i], sd_in[i], wts, (0.05, 0.5, 0.95)) for i in range(p)])
    j = int(np.argmax(wts))
    info = {"direction_ln": v.tolist(), "laplace_sd_along": float(sd_v), "step_ln": float(step),
            "gauss_newton_end_ln": u0.tolist(), "cov_other_ln": C_other.tolist(),
            "points": [{"offset_sd": k * s.ridge_step_sd, "u_ln": grid[k][1].tolist(),
                        "minus2_log_posterior": grid[k][0], "chi2": grid[k][2]} for k in ks],
            "weights": wts.tolist(), "chi2_at_estimate": float(grid[ks[j]][2])}
    return qs[:, 1], qs[:, 0], qs[:, 2], cov, info


def _mixture_quantiles(m: np.ndarray, sd: float, w: np.ndarray, probs) -> list[float]:
    """Quantiles of the normal mixture sum_j w_j N(m_j, sd^2) (bisection on its CDF)."""
    from math import erf, sqrt

    def cdf(x):
        return float(sum(wj * 0.5 * (1.0 + erf((x - mj) / (sd * sqrt(2.0)))) for wj, mj in zip(w, m)))

    out = []
    for pr in probs:
        a, b = float(m.min() - 10 * sd), float(m.max() + 10 * sd)
        for _ in range(80):
            c = 0.5 * (a + b)
            a, b = (c, b) if cdf(c) < pr else (a, c)
        out.append(0.5 * (a + b))
    return out


def local_information(card: ModelCard, histories: Sequence[History], names: Sequence[str], u: np.ndarray,
                      seed: int = 0, settings: FitSettings | None = None, client=None,
                      progress: Callable[[int], None] | None = None) -> dict:
    """Identifiability at one point: Fisher information of the summaries, posterior sd, verdicts.

    One design (2p + 1 points x replicates plant runs per history) at ``u`` = ln(value / card
    value); no data are needed beyond the histories' schedules, times and sample sizes (their
    measured samples set the sampling covariance). Answers "which parameters would these
    experiments identify?" before running them.

    Parameters
    ----------
    card : ModelCard
    histories : sequence of History
    names : sequence of str
    u : ndarray
        Point (ln ratio to the card) to evaluate at, e.g. the truth in a synthetic study.
    seed : int, optional
    settings : FitSettings, optional
    client : distributed.Client, optional
    progress : callable, optional

    Returns
    -------
    dict
        ``fisher``, ``cov_u``, ``sd_ratio`` (posterior / prior sd), ``identified``, ``why``.
    """
    s = settings or FitSettings()
    names = list(names)
    y, obs_cov, ev = _setup(card, names, histories, s, seed, client, progress)
    S = ev.run(_design(np.asarray(u, float), s.fd_step))
    W = _weight(obs_cov, S.var(axis=1, ddof=1).mean(axis=0), s.replicates)
    J, F = _jacobian_information(S, W, s.fd_step)
    cov = np.linalg.inv(F + np.eye(len(names)) / s.prior_sd**2)
    ratio = np.sqrt(np.diag(cov)) / s.prior_sd
    identified, why = _identifiability(names, F, ratio, s, bounds_hit(ev, u))
    return {"fisher": F, "cov_u": cov, "sd_ratio": ratio, "identified": identified, "why": why,
            "plant_runs": ev.runs}


def bounds_hit(ev, u: np.ndarray) -> list[str | None]:
    """Per parameter: ``"lower"`` or ``"upper"`` where ``card value * exp(u)`` is at or past the card's
    range of that constant (the plant ran it at the bound: :meth:`_Evaluator.values`), else None."""
    raw = ev.card_values * np.exp(np.asarray(u, dtype=float))
    return ["upper" if r >= hi else "lower" if r <= lo else None for r, lo, hi in zip(raw, ev.lo, ev.hi)]


def _identifiability(names, F: np.ndarray, ratio: np.ndarray, s: FitSettings,
                     at_bound: Sequence[str | None] | None = None) -> tuple[list[bool], list[str]]:
    """Which parameters the data identify: posterior sd vs prior sd, and the Fisher information. An
    estimate at the card's bound of its constant (``at_bound``) is not identified, however narrow: the
    data push it past the range the card accepts, and the plant runs it at the bound."""
    lam, vec = np.linalg.eigh(F)
    prior_prec = 1.0 / s.prior_sd**2
    identified, why = [], []
    for i, n in enumerate(names):
        side = (at_bound or [None] * len(names))[i]
        if side is not None:
            identified.append(False)
            why.append(f"the estimate of {n} is at the {side} bound of the range the card accepts: the data "
                       "push it further, the plant ran it at the bound, and its interval measures nothing")
            continue
        ok = bool(ratio[i] <= s.unidentified_ratio)
        identified.append(ok)
        if ok:
            why.append(f"posterior sd of ln {n} is {ratio[i]:.2f} of the prior's")
            continue
        # the Fisher direction with least information that loads most on this parameter
        k = int(np.argmax(np.abs(vec[i, :]) / np.sqrt(np.maximum(lam, 1e-30))))
        weak = ", ".join(f"{vec[j, k]:+.2f} ln {m}" for j, m in enumerate(names) if abs(vec[j, k]) > 0.2)
        info = lam[k] / prior_prec
        if abs(vec[i, k]) > 0.9:
            cause = "the summaries barely respond to it"
        else:
            cause = f"only the combination ({weak}) is constrained weakly; it trades off against the others"
        why.append(f"posterior sd of ln {n} is {ratio[i]:.2f} of the prior's (data narrow it less than "
                   f"{1 / s.unidentified_ratio:.0f}-fold); weakest Fisher direction carries {info:.2g} x the prior's "
                   f"information: {cause}")
    return identified, why
