"""A trial written as a campaign: the stochastic plant stands in for the person at the mill and
the micrograph sampler for the SEM, driving the real campaign verbs (advise, decide, log, sample).

With the same scenario and seed it makes exactly the calls of ``bmctl trial``
(:func:`bmctl.trial.run_trial`): the plant and the sampler come from :func:`bmctl.trial.build`,
the campaign's filter from the same SeedSequence child, and the campaign's estimator timeline
processes "log, then sample at its end" as the trial's predict-then-update. The trajectory is
therefore the trial's (``tests/campaign/test_campaign.py`` checks it).

``bmctl trial SCENARIO --campaign`` (:func:`run_trial_as_campaign`) leaves the campaign in
``OUT/campaign/`` (openable by ``bmctl campaign status/report``) beside the trial's usual
``trajectory.csv``, ``summary.json`` and ``trial.png``. It does not resume: the campaign's
database would continue, but the simulated plant's powder and the sampler's generator live
outside it (a plain trial keeps them in ``checkpoint.npz``); the same seed in a new folder
gives the same trajectory.
"""

from __future__ import annotations

import json
from pathlib import Path

from ..errors import InputError
from ..naming import arg
from ..physics.constants import TIME_EPS_H
from . import workflow as wf

#: the campaign's folder inside a trial's output folder
CAMPAIGN_DIR = "campaign"


class _NoEstimator:
    """The trial loop's estimator slot, unused: the campaign estimates."""

    def predict(self, u, dt_h):
        pass

    def estimate(self):
        class _E:
            def as_dict(self):
                return {}

        return _E()


def check_scenario(sc, path) -> None:
    """Refuse (one line) a scenario whose trial a campaign cannot reproduce: a campaign's
    estimator is the particle filter (its settings, the scenario's ``[estimator.pf]``, are recorded
    in the campaign), and its targets are single values."""
    if sc.estimator.kind != "pf":
        raise InputError(f"{path}: estimator.kind: a campaign runs the particle filter, not {sc.estimator.kind!r} "
                         "(drop --campaign to run this trial)")
    for key, value in dict(sc.target).items():
        if isinstance(value, (list, tuple)):
            lo, hi = (float(v) for v in value)
            raise InputError(f"{path}: target.{key}: a campaign steers to one value, not a window (e.g. {key} = "
                             f"{(lo + hi) / 2:g}); drop --campaign to run the window")


def _tally_binding(loop, stats: dict) -> None:
    """Tally the limits the first and the latest plan run against into the trial's ``stats``
    (``binding_first``, ``binding_last``), as :meth:`bmctl.loop.ClosedLoop.decide` does for a plain
    trial: every plan of ``loop`` (the campaign's, :meth:`bmctl.campaign.mill.CampaignLoop.decide_at`)
    that names its binding limits (a plan on operable schedules) counts."""
    decide_at = loop.decide_at

    def tallied(t_h, history=None):
        plan, solve_ms = decide_at(t_h, history=history)
        extra = getattr(plan, "extra", None)
        binding = extra.get("binding") if isinstance(extra, dict) else None
        if binding is not None:
            stats.setdefault("binding_first", [str(b) for b in binding])
            stats["binding_last"] = [str(b) for b in binding]
        return plan, solve_ms

    loop.decide_at = tallied


def trial_steps(scenario_path, folder, seed: int = 0, on_start=None):
    """Run a trial scenario through the campaign verbs, one control interval at a time.

    Parameters
    ----------
    scenario_path : path-like
        Scenario TOML (``scenarios/trial-*.toml``).
    folder : path-like
        New campaign folder.
    seed : int
        Seed of the trial (plant, filter and sampler generators are spawned from it, as ``bmctl trial``).
    on_start : callable, optional
        Called with the plant before the first step (``run_trial_as_campaign`` records its state at
        t = 0); it must draw nothing from the plant's generator.

    Yields
    ------
    (ClosedLoop, StepRecord, dict)
        The trial's loop (its plant, sampler and tallies; its estimator and controller are
        unused), the step's record as ``bmctl trial`` writes it, and the step's advice.
    """
    from ..control.base import Status
    from ..loop import StepRecord, interval_length, interval_share
    from ..measure.tables import ParticleTable
    from ..scenario import load_scenario, resolve
    from ..trial import build

    sc = load_scenario(scenario_path)
    check_scenario(sc, scenario_path)
    base = Path(scenario_path).resolve().parent
    trial_loop = build(sc, base, seed)
    trial_loop.estimator = _NoEstimator()
    plant, sensor = trial_loop.mill, trial_loop.sensor
    if on_start is not None:
        on_start(plant)
    wf.init(folder, resolve(sc.model, base), resolve(sc.controller.config, base), dict(sc.target), hours=sc.hours,
            temperature_max_c=sc.temperature_max_c, seed=seed, particles=sc.estimator.particles,
            estimator=dict(sc.estimator.pf))
    stats = trial_loop.stats
    with wf.Campaign(folder) as c:
        _tally_binding(c.loop, stats)
        interval = c.loop.controller.interval_h
        kind = c.meta["controller_kind"]
        if sc.sampling.feed:  # the feed before anything runs, as ClosedLoop.observe_feed
            s_um, rr = sensor.sample(plant, trial_loop.sample_rng)
            wf.sample(folder, 0.0, [ParticleTable.from_size_aspect(s_um, rr)], campaign=c)
            stats["feed_sampled"] = True
        for k in range(trial_loop.steps):
            t = c.clock_h()
            advice = wf.advise(folder, campaign=c)
            wf.decide(folder, True, campaign=c)
            _, _, rpm, milling, *_ = c.latest_plan()
            status = Status(kind, advice["solver_status"], advice["solver_ok"], fallback=advice["fallback"])
            stats["solve_ms"].append(advice["solve_ms"])  # the tallies of ClosedLoop.decide
            stats["fallbacks"] += int(status.fallback != "none")
            stats["solver_failures"] += int(not status.success)
            if status.fallback != "none" or not status.success:
                stats.setdefault("log", []).append(f"t={t:g} h: {advice['solver']}")
            dt = interval_length(t, sc.hours, interval)
            milling = interval_share(milling, interval, dt)  # the advised minutes in a short last interval
            trial_loop.apply(rpm, milling, dt)
            t_new = t + dt
            due = t_new >= trial_loop.next_sample_h - TIME_EPS_H or t_new >= sc.hours - TIME_EPS_H
            T = plant.temperature_c if due and sc.sampling.temperature_reading else None
            est = wf.log(folder, rpm, dt, milling, temperature_c=T, campaign=c)["estimate"]
            if due:
                s_um, rr = sensor.sample(plant, trial_loop.sample_rng)
                trial_loop.next_sample_h += sc.sampling.every_h
                est = wf.sample(folder, t_new, [ParticleTable.from_size_aspect(s_um, rr)], campaign=c)["estimate"]
            trial_loop.k, trial_loop.est, trial_loop.u_prev = k + 1, est, (rpm, milling)
            truth = {**plant.moments(), "peak_temperature_c": trial_loop.peak_c}
            yield trial_loop, StepRecord(k, t_new, rpm, milling, truth, est, int(due),
                                         advice["solve_ms"], status), advice


def run_as_campaign(scenario_path, folder, seed: int = 0) -> list[dict]:
    """Run a trial scenario through the campaign verbs; returns one row per control interval
    (``t_h, rpm, milling``, the plant's ``true`` moments and the campaign's ``estimate``)."""
    return [{"k": rec.k, "t_h": rec.t_h, "rpm": rec.rpm, "milling": rec.milling, "true": rec.truth,
             "estimate": rec.estimate, "sampled": rec.sampled}
            for _, rec, _ in trial_steps(scenario_path, folder, seed)]


def run_trial_as_campaign(scenario_path, out, seed: int = 0, progress=None) -> dict:
    """``bmctl trial --campaign``: a trial run through the campaign verbs, with the trial's outputs.

    Writes ``out/campaign/`` (the campaign), ``out/trial.json``, ``out/trajectory.csv`` (the columns
    of ``bmctl trial``, rewritten atomically after every interval), and at the end
    ``out/summary.json`` and ``out/trial.png``. Returns the summary.

    Parameters
    ----------
    scenario_path : path-like
        Scenario TOML.
    out : path-like
        New output folder (refused if it already holds a trial or a campaign).
    seed : int
        Seed of the trial.
    progress : callable, optional
        Called after each interval with (k, K).
    """
    from .. import io
    from ..scenario import load_scenario
    from ..trial import (_plant_card, check_resolvable, figures, start_truth, summarise, trajectory_header,
                         trajectory_row)

    sc = load_scenario(scenario_path)
    check_scenario(sc, scenario_path)
    check_resolvable(sc, scenario_path, _plant_card(sc, Path(scenario_path).resolve().parent))
    out = Path(out)
    traj, folder = out / "trajectory.csv", out / CAMPAIGN_DIR
    if traj.exists() or folder.exists():
        raise InputError(f"{arg('out')}: {out} already holds a trial; give another folder (a trial run as a campaign "
                         "does not resume)")
    out.mkdir(parents=True, exist_ok=True)
    meta = {"scenario": str(Path(scenario_path).resolve()), "seed": seed, "campaign": CAMPAIGN_DIR}

    def record_start(plant):  # with the plant at t = 0, for trial.png (trajectory.csv has interval ends only)
        io.write_text(out / "trial.json", json.dumps({**meta, "start": start_truth(plant)}))

    header = ",".join(trajectory_header()) + "\n"
    rows: list[str] = []
    loop = None
    for loop, rec, _ in trial_steps(scenario_path, folder, seed, on_start=record_start):
        rows.append(io.csv_text([], [trajectory_row(rec)]).splitlines()[-1] + "\n")
        io.write_text(traj, header + "".join(rows))
        if progress is not None:
            progress(loop.k, loop.steps)
    summary = summarise(sc, loop)
    summary["campaign"] = str(folder)
    io.write_text(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    figures(sc, traj, out, loop.cfg.ceiling_c)
    return summary
