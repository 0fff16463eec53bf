"""A trial written as a campaign: the stochastic plant stands in for the person at the mill and
the micrograph sampler for the SEM, driving the real campaign verbs (advise, decide, log, sample).

With the same scenario and seed it makes exactly the calls of ``bmctl trial``
(:func:`bmctl.trial.run_trial`): the plant and the sampler come from :func:`bmctl.trial.build`,
the campaign's filter from the same SeedSequence child, and the campaign's estimator timeline
processes "log, then sample at its end" as the trial's predict-then-update. The trajectory is
therefore the trial's (``tests/test_campaign.py`` checks it).
"""

from __future__ import annotations

from pathlib import Path

from ..physics.constants import TIME_EPS_H
from . import workflow as wf


class _NoEstimator:
    """The trial loop's estimator slot, unused: the campaign estimates."""

    def predict(self, u, dt_h):
        pass

    def estimate(self):
        class _E:
            def as_dict(self):
                return {}

        return _E()


def run_as_campaign(scenario_path, folder, seed: int = 0) -> list[dict]:
    """Run a trial scenario through the campaign verbs; returns one row per control interval
    (``t_h, rpm, milling``, the plant's ``true`` moments and the campaign's ``estimate``)."""
    from ..measure.tables import ParticleTable
    from ..scenario import load_scenario
    from ..trial import build

    sc = load_scenario(scenario_path)
    base = Path(scenario_path).resolve().parent
    trial_loop = build(sc, base, seed)
    trial_loop.estimator = _NoEstimator()
    plant, sensor = trial_loop.mill, trial_loop.sensor
    from ..scenario import resolve

    wf.init(folder, resolve(sc.model, base), resolve(sc.controller.config, base), dict(sc.target), hours=sc.hours,
            temperature_max_c=sc.temperature_max_c, seed=seed, particles=sc.estimator.particles)
    rows = []
    with wf.Campaign(folder) as c:
        interval = c.loop.controller.interval_h
        steps = trial_loop.steps
        for k in range(steps):
            t = c.clock_h()
            wf.advise(folder, campaign=c)
            wf.decide(folder, True, campaign=c)
            _, _, rpm, milling, *_ = c.latest_plan()
            dt = min(interval, sc.hours - t)
            trial_loop.apply(rpm, milling, dt)
            t_new = t + dt
            due = t_new >= trial_loop.next_sample_h - TIME_EPS_H or t_new >= sc.hours - TIME_EPS_H
            T = plant.temperature_c if due and sc.sampling.temperature_reading else None
            r = wf.log(folder, rpm, dt, milling, temperature_c=T, campaign=c)
            est = r["estimate"]
            if due:
                s_um, rr = sensor.sample(plant, trial_loop.sample_rng)
                trial_loop.next_sample_h += sc.sampling.every_h
                est = wf.sample(folder, t_new, [ParticleTable.from_size_aspect(s_um, rr)], campaign=c)["estimate"]
            rows.append({"k": k, "t_h": t_new, "rpm": rpm, "milling": milling, "true": plant.moments(),
                         "estimate": est, "sampled": int(due)})
    return rows
