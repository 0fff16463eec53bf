"""How closely the campaign's filter reads the powder along the hidden-mill schedules, and whether its
noise settings could read it closer.

    nice python benchmarks/estimate_replay.py   # writes results/estimate_replay.json (~20 min on two cores)

The schedules the campaigns ran (the step logs of the five default hidden-mill results files:
``hidden_mills``, ``hidden_mills_seed1_all``, ``hidden_mills_seed2_all``, ``hidden_mills_heldout``,
``hidden_mills_heldout_seed1``; 31 runs) are replayed open loop on a fresh hidden plant of each mill
(3000 particles, its own seed), with a 300-particle micrograph sample every hour. The campaign's filter
(1000 particles, the laboratory card's moment model, ``CAMPAIGN_FILTER``) follows each replay once per
variant of its noise settings; every variant sees the same plant and the same samples. Printed and
written per variant: the RMS and the mean of the estimate's relative error in s_mean at the samples (all,
and the last three of each run), beside the same for one sample's own mean. The filter cannot read the
powder much closer than the samples allow when its model's one-hour prediction is itself uncertain by
about as much: a variant that trusts the model more (lower noise floors, no adaptation) reads it
closer only if that prediction is better than the filter assumes.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

FILES = ("hidden_mills", "hidden_mills_seed1_all", "hidden_mills_seed2_all", "hidden_mills_heldout",
         "hidden_mills_heldout_seed1")
SAMPLE, PLANT, FILTER = 300, 3000, 1000
#: the campaign's filter, and changes of it that trust the moment model more or carry more particles
VARIANTS = {
    "campaign": {},
    "floor_half": {"process_noise_floor": (0.025, 0.04, 0.2, 0.2)},
    "floor_quarter": {"process_noise_floor": (0.0125, 0.02, 0.2, 0.2)},
    "no_adaptation_low_noise": {"adapt": False, "process_noise_per_sqrt_h": (0.03, 0.05, 0.8, 0.8)},
    "no_drift_walk": {"size_drift_walk_per_sqrt_h": 0.0},
    "particles_4000": {"n_particles": 4000},
}


def replay(task: tuple, rng: np.random.Generator) -> dict[str, tuple[list, list]]:
    """{variant: (estimate errors %, sample-mean errors %)} at each hourly sample of one replayed run.

    ``task`` is plain data (the hidden card as a dict, the laboratory card's path, the logged steps);
    every variant restarts the plant, filter and sampler streams from ``rng``'s seed sequence, so all
    of them see the same plant and the same samples."""
    from bmctl.campaign.workflow import CAMPAIGN_FILTER
    from bmctl.config import ModelCard
    from bmctl.estimate import FilterSettings, ParticleFilter
    from bmctl.measure.sampler import micrograph_sample
    from bmctl.moments.forcard import for_card
    from bmctl.plant.plant import Plant

    hidden, card_path, steps, interval_h = task
    hidden = ModelCard.model_validate(hidden)
    model = for_card(card_path)
    ss = rng.bit_generator.seed_seq
    out = {}
    for name, changes in VARIANTS.items():
        g_plant, g_pf, g_sample = (np.random.default_rng(s) for s in
                                   np.random.SeedSequence(ss.entropy, spawn_key=ss.spawn_key).spawn(3))
        plant = Plant(hidden, g_plant, PLANT)
        pf = ParticleFilter(model, g_pf, FilterSettings(**{**CAMPAIGN_FILTER, "n_particles": FILTER, **changes}))
        t, est_err, raw_err = 0.0, [], []
        for st in steps:
            mill_h = st["mill_min"] / 60.0
            if mill_h > 0:
                plant.advance(st["rpm"], mill_h, milling=1.0)
            if interval_h - mill_h > 1e-9:
                plant.advance(0.0, interval_h - mill_h, milling=0.0)
            pf.predict((st["rpm"], mill_h / interval_h), interval_h)
            t += interval_h
            if abs(t - round(t)) < 1e-6:  # the hourly sample
                tab = micrograph_sample(plant.s * 1e6, plant.r, SAMPLE, g_sample)
                est = pf.update(s_um=tab.s_um, r=tab.r)
                true = plant.moments()["s_mean_um"]
                est_err.append(100 * (est.as_dict()["s_mean_um"] / true - 1))
                raw_err.append(100 * (float(np.mean(tab.s_um)) / true - 1))
        out[name] = (est_err, raw_err)
    return out


def _stats(runs: list[list[float]]) -> dict:
    every = np.concatenate([np.asarray(r) for r in runs])
    last3 = np.concatenate([np.asarray(r[-3:]) for r in runs])
    return {"rms_pct": float(np.sqrt(np.mean(every**2))), "mean_pct": float(every.mean()),
            "last3_rms_pct": float(np.sqrt(np.mean(last3**2))), "n": int(every.size)}


def main() -> None:
    import hidden_mills as hm

    from tqdm import tqdm

    from bmctl.parallel import client_for, close_client, map_seeded
    from bmctl.results import load_results, write_results

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=0, help="replay only the first N runs (0: all)")
    ap.add_argument("--workers", type=int, default=None, help="worker processes (default: the machine's cores)")
    ap.add_argument("--no-results", action="store_true", help="do not write results/estimate_replay.json")
    a = ap.parse_args()
    cases = {c.name: c for c in hm.CASES + hm.HELD_OUT}
    recs = {f: load_results(f) for f in FILES}
    jobs = [(f, rec["settings"]["seed"], row) for f, rec in recs.items() for row in rec["cases"]]
    if a.runs > 0:
        jobs = jobs[: a.runs]
    tasks = [(hm.hidden_card(cases[row["case"]]).model_dump(), str(hm.CARD), row["steps"], hm.INTERVAL_H)
             for _, _, row in jobs]
    seeds = [np.random.SeedSequence([seed, *map(ord, row["case"]), 77]) for _, seed, row in jobs]  # one per run
    client = client_for(None, a.workers)
    try:
        with tqdm(total=len(tasks), desc="replays", unit="run") as bar:
            results = map_seeded(replay, tasks, seeds, client, progress=bar.update)
    finally:
        close_client(client)
    est = {k: [res[k][0] for res in results] for k in VARIANTS}
    raw = [res["campaign"][1] for res in results]
    for (f, _, row), res in zip(jobs, results):
        print(f"{f} {row['case']}: " + ", ".join(f"{k} {np.sqrt(np.mean(np.square(v[0]))):.2f}"
                                                for k, v in res.items()) + " % RMS")
    rec = {"sample_mean": _stats(raw), "variants": {k: {"changes": {c: list(v) if isinstance(v, tuple) else v
                                                                     for c, v in VARIANTS[k].items()},
                                                        **_stats(v)} for k, v in est.items()},
           "runs": len(jobs)}
    print(f"one sample's mean: RMS {rec['sample_mean']['rms_pct']:.2f} % over {rec['sample_mean']['n']} samples")
    for k, v in rec["variants"].items():
        print(f"{k:>24}: estimate RMS {v['rms_pct']:.2f} % (mean {v['mean_pct']:+.2f} %), last three samples of "
              f"each run {v['last3_rms_pct']:.2f} %")
    if not a.no_results and a.runs == 0:
        print("wrote", write_results("estimate_replay", rec,
                                     settings={"files": list(FILES), "sample_particles": SAMPLE,
                                               "plant_particles": PLANT, "filter_particles": FILTER,
                                               "interval_h": hm.INTERVAL_H},
                                     command="python benchmarks/estimate_replay.py"))


if __name__ == "__main__":
    main()
