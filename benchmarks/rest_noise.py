"""How well the campaign's filter reads a resting mill: moment noise on wall hours vs milled hours.

    nice python benchmarks/rest_noise.py          # writes results/rest_noise.json (~6 min on two cores)

Hidden mill F of ``benchmarks/hidden_mills.py`` (the laboratory card with gamma x1.6, delta x1.3 and a
ball-to-powder ratio of 9.5) mills 3 h at 300 rpm and then rests 7 h; a 300-particle micrograph
sample of its plant (3000 particles) is taken every hour. The campaign's filter (1000 particles, the
laboratory card's moment model, ``CAMPAIGN_FILTER``) follows it with ``rest_noise_fraction`` 1 (the
moments take discrepancy noise on wall hours), the campaign's 0.02, and 0. Printed per hour: the
RMS over seeds of the relative error of the estimated s_mean against the plant's, and the rest
hours' mean of that (one sample mean's own scatter: ``hidden_mills.py --noise``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

MILL_H, REST_H, RPM, SAMPLE, PLANT, FILTER = 3, 7, 300.0, 300, 3000, 1000


def run(fraction: float, seeds: int) -> np.ndarray:
    """(seeds, hours) relative errors (%) of the estimated s_mean after each hourly sample."""
    import hidden_mills as hm

    from bmctl.campaign.workflow import CAMPAIGN_FILTER
    from bmctl.estimate import FilterSettings, ParticleFilter
    from bmctl.measure.sampler import micrograph_sample
    from bmctl.moments.forcard import for_card
    from bmctl.plant.plant import Plant

    model = for_card(hm.CARD)
    case = next(c for c in hm.CASES if c.name == "F")
    out = np.empty((seeds, MILL_H + REST_H))
    for seed in range(seeds):
        g_plant, g_pf, g_sample = (np.random.default_rng(s) for s in np.random.SeedSequence([seed, 5]).spawn(3))
        plant = Plant(hm.hidden_card(case), g_plant, PLANT)
        st = FilterSettings(**{**CAMPAIGN_FILTER, "rest_noise_fraction": fraction, "n_particles": FILTER})
        pf = ParticleFilter(model, g_pf, st)
        for h in range(MILL_H + REST_H):
            u = (RPM, 1.0) if h < MILL_H else (0.0, 0.0)
            plant.advance(u[0], 1.0, milling=u[1])
            pf.predict(u, 1.0)
            tab = micrograph_sample(plant.s * 1e6, plant.r, SAMPLE, g_sample)
            est = pf.update(s_um=tab.s_um, r=tab.r)
            out[seed, h] = 100 * (est.as_dict()["s_mean_um"] / plant.moments()["s_mean_um"] - 1)
    return out


def main() -> None:
    from bmctl.results import write_results

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=16)
    ap.add_argument("--no-results", action="store_true", help="do not write results/rest_noise.json")
    a = ap.parse_args()
    rec = {}
    for key, frac in (("wall_hours", 1.0), ("campaign", 0.02), ("milled_hours_only", 0.0)):
        E = run(frac, a.seeds)
        rms = np.sqrt(np.mean(E**2, axis=0))
        rec[key] = {"rest_noise_fraction": frac, "rms_pct": rms.tolist(), "mean_pct": E.mean(axis=0).tolist(),
                    "rest_rms_mean_pct": float(rms[MILL_H:].mean()), "last_rms_pct": float(rms[-1])}
        print(f"rest_noise_fraction {frac:g}: RMS error % by hour " + " ".join(f"{v:.2f}" for v in rms)
              + f"; rest hours mean {rec[key]['rest_rms_mean_pct']:.2f} %")
    if not a.no_results:
        print("wrote", write_results("rest_noise", {"fractions": rec},
                                     settings={"mill": "F", "mill_h": MILL_H, "rest_h": REST_H, "rpm": RPM,
                                               "sample_particles": SAMPLE, "plant_particles": PLANT,
                                               "filter_particles": FILTER, "seeds": a.seeds},
                                     command="python benchmarks/rest_noise.py"))


if __name__ == "__main__":
    main()
