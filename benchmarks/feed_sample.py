"""How well the campaign's filter reads a feed that is not the card's: a sample before any milling.

    nice python benchmarks/feed_sample.py          # writes results/feed_sample.json (~2 min on one core)

The plant is the laboratory card with its starting powder (``[initial]`` s_mean_um, s_std_um)
replaced by a feed of 0.7, 1 or 1.5 times the card's mean size and 2.5 times its spread (a coarser,
broader lot). A 300-particle micrograph sample of the feed is taken at 0 h, then the plant mills
3 h at 300 rpm with an hourly sample. The campaign's filter (1000 particles, the card's moment
model, ``CAMPAIGN_FILTER``) follows it twice on the same plant and samples: with the feed's prior
(``feed_log_std`` = 1, the default) and with the card's starting powder held (0). Printed per feed:
the relative error of the estimated s_mean against the plant's after the feed sample and after each
hour (RMS over seeds), how often the 90 % interval holds the plant's mean at 0 h, and the median
ratio q95/q05 of gamma_mult after the feed sample (its prior's is 3.7: a feed says nothing of it)
and after the last hour.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
FEEDS = {"x0p7": 0.7, "x1": 1.0, "x1p5": 1.5}  # feed mean size over the card's
SPREAD_FACTOR = 2.5  # feed s_std over the card's
MILL_H, RPM, SAMPLE, PLANT, FILTER = 3, 300.0, 300, 3000, 1000
SETTINGS = {"feed_prior": 1.0, "card_held": 0.0}


def run(factor: float, seeds: int) -> dict:
    """Per setting: (seeds, 1 + MILL_H) relative errors (%), coverage at 0 h, gamma_mult q95/q05 at 0 h."""
    from bmctl.campaign.workflow import CAMPAIGN_FILTER
    from bmctl.config import load_card
    from bmctl.estimate import FilterSettings, ParticleFilter
    from bmctl.measure.sampler import micrograph_sample
    from bmctl.moments.forcard import for_card
    from bmctl.plant.plant import Plant

    model = for_card(CARD)
    card = load_card(CARD)
    d = card.model_dump()
    d["initial"]["s_mean_um"] *= factor
    d["initial"]["s_std_um"] *= SPREAD_FACTOR
    feed_card = type(card).model_validate(d)
    out = {k: {"err": np.empty((seeds, 1 + MILL_H)), "covered": 0, "gamma_ratio": [], "gamma_ratio_last": []}
           for k in SETTINGS}
    for seed in range(seeds):
        s_plant, s_pf, s_sample = np.random.SeedSequence([seed, 11]).spawn(3)
        plant, g_sample = Plant(feed_card, np.random.default_rng(s_plant), PLANT), np.random.default_rng(s_sample)
        filters = {k: ParticleFilter(model, np.random.default_rng(s_pf),  # the same draws for both
                                     FilterSettings(**{**CAMPAIGN_FILTER, "n_particles": FILTER, "feed_log_std": v}))
                   for k, v in SETTINGS.items()}
        for h in range(1 + MILL_H):
            if h:
                plant.advance(RPM, 1.0, milling=1.0)
            tab = micrograph_sample(plant.s * 1e6, plant.r, SAMPLE, g_sample)
            truth = plant.moments()["s_mean_um"]
            for k, pf in filters.items():
                if h:
                    pf.predict((RPM, 1.0), 1.0)
                est = pf.update(s_um=tab.s_um, r=tab.r).as_dict()
                out[k]["err"][seed, h] = 100 * (est["s_mean_um"] / truth - 1)
                if h == 0:
                    out[k]["covered"] += int(est["s_mean_um_q05"] <= truth <= est["s_mean_um_q95"])
                    out[k]["gamma_ratio"].append(est["gamma_mult_q95"] / est["gamma_mult_q05"])
                if h == MILL_H:
                    out[k]["gamma_ratio_last"].append(est["gamma_mult_q95"] / est["gamma_mult_q05"])
    return out


def main() -> None:
    from bmctl.results import write_results

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--no-results", action="store_true", help="do not write results/feed_sample.json")
    a = ap.parse_args()
    rec = {}
    for name, factor in FEEDS.items():
        res = run(factor, a.seeds)
        rec[name] = {}
        for k, r in res.items():
            rms = np.sqrt(np.mean(r["err"] ** 2, axis=0))
            rec[name][k] = {"rms_pct": rms.tolist(), "feed_rms_pct": float(rms[0]), "last_rms_pct": float(rms[-1]),
                            "feed_coverage": r["covered"] / a.seeds,
                            "gamma_q95_over_q05": float(np.median(r["gamma_ratio"])),
                            "gamma_q95_over_q05_last": float(np.median(r["gamma_ratio_last"]))}
            print(f"feed {name}, {k:<10}: RMS error % at 0 h (the feed sample) and after each hour "
                  + " ".join(f"{v:.2f}" for v in rms)
                  + f"; 90 % interval holds the feed's mean in {r['covered']} of {a.seeds}; "
                  f"gamma_mult q95/q05 {rec[name][k]['gamma_q95_over_q05']:.2f} at 0 h, "
                  f"{rec[name][k]['gamma_q95_over_q05_last']:.2f} at {MILL_H} h")
    if not a.no_results:
        print("wrote", write_results("feed_sample", {"feeds": rec},
                                     settings={"feeds": FEEDS, "spread_factor": SPREAD_FACTOR, "mill_h": MILL_H,
                                               "rpm": RPM, "sample_particles": SAMPLE, "plant_particles": PLANT,
                                               "filter_particles": FILTER, "seeds": a.seeds},
                                     command="python benchmarks/feed_sample.py"))


if __name__ == "__main__":
    main()
