"""How well can the card's moment model describe each hidden mill? The best (gamma, delta) per mill.

    nice python benchmarks/model_form.py [--particles 5000] [--seed 0]

For every mill of ``benchmarks/hidden_mills.py`` (A-G and the held-out H-L) the hidden plant runs
plain schedules (one rpm held for the mill's batch: 150, 220, 300 and 380 rpm) and its mean size
is read every hour. The card's moment model is then fitted to all of those points at once by its
two multipliers gamma and delta (least squares on the relative error, ``scipy.optimize.
least_squares`` in log space from nine starts), which is the most the campaign's particle filter can learn about a
mill. What is left is the model's *form* error on that mill: printed and written per mill and per
rpm to ``results/model_form.json`` (``bmctl.results``), with the card's own error (gamma = delta =
1) beside it. A mill whose form error is large at some rpm is one where the plans' predictions at
that rpm stay wrong however long the filter learns.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

RPMS = (150.0, 220.0, 300.0, 380.0)
STEP_H = 0.5


def plant_curves(card, hours: float, particles: int, seed: int) -> np.ndarray:
    """Hourly plant mean size (um), (len(RPMS), hours) for each held rpm."""
    from bmctl.plant.plant import Plant

    out = []
    for k, rpm in enumerate(RPMS):
        plant = Plant(card, np.random.default_rng(np.random.SeedSequence([seed, k])), particles)
        row = []
        for _ in range(int(round(hours))):
            plant.advance(rpm, 1.0, milling=1.0)
            row.append(float(plant.moments()["s_mean_um"]))
        out.append(row)
    return np.array(out)


def model_curves(model, hours: float, p) -> np.ndarray:
    """Hourly moment-model mean size (um) for each held rpm, multipliers ``p``."""
    n = int(round(hours / STEP_H))
    every = int(round(1.0 / STEP_H))
    out = []
    for rpm in RPMS:
        X = model.simulate(model.x0(), [[rpm, 1.0]] * n, STEP_H, p=np.asarray(p, dtype=float))
        out.append(X[every::every, 0])
    return np.array(out)


def fit(model, hours: float, Y: np.ndarray) -> dict:
    from scipy.optimize import least_squares

    def resid(q):
        M = model_curves(model, hours, np.exp(q))
        r = (M - Y) / Y
        return np.where(np.isfinite(r), r, 10.0).ravel()

    lo, hi = np.log([0.2, 0.2]), np.log([5.0, 5.0])
    starts = [np.log([g, d]) for g in (0.5, 1.0, 2.0) for d in (0.5, 1.0, 2.0)]  # the fit is not convex
    sol = min((least_squares(resid, x0, bounds=(lo, hi), x_scale=0.5) for x0 in starts), key=lambda r: r.cost)
    p = np.exp(sol.x)
    R = resid(sol.x).reshape(Y.shape)
    R0 = resid(np.zeros(2)).reshape(Y.shape)
    per = {f"{r:.0f}": float(100 * np.sqrt(np.mean(R[i] ** 2))) for i, r in enumerate(RPMS)}
    worst = max(per, key=per.get)
    return {"gamma_fit": float(p[0]), "delta_fit": float(p[1]), "rms_pct": float(100 * np.sqrt(np.mean(R ** 2))),
            "rms_card_pct": float(100 * np.sqrt(np.mean(R0 ** 2))), "rms_by_rpm_pct": per, "worst_rpm": float(worst),
            "worst_rpm_rms_pct": per[worst]}


def main() -> None:
    import hidden_mills as hm
    from bmctl.moments import make_moment_model
    from bmctl.results import write_results

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--particles", type=int, default=5000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-results", action="store_true")
    a = ap.parse_args()
    model = make_moment_model(str(hm.CARD))
    rows = []
    for case in hm.CASES + hm.HELD_OUT:
        Y = plant_curves(hm.hidden_card(case), case.hours, a.particles, a.seed)
        r = {"case": case.name, "gamma": case.gamma, "delta": case.delta, "field": case.field, "value": case.value,
             "hours": case.hours, **fit(model, case.hours, Y)}
        rows.append(r)
        print(f"{case.name}: gamma x{case.gamma:g}, delta x{case.delta:g}, {case.field} = {case.value:g}: fitted "
              f"gamma x{r['gamma_fit']:.2f}, delta x{r['delta_fit']:.2f}; form error {r['rms_pct']:.1f} % RMS "
              f"(card {r['rms_card_pct']:.1f} %), worst at {r['worst_rpm']:.0f} rpm: {r['worst_rpm_rms_pct']:.1f} %",
              flush=True)
    summary = {"median_rms_pct": float(np.median([r["rms_pct"] for r in rows])),
               "max_rms_pct": float(max(r["rms_pct"] for r in rows)),
               "median_rms_card_pct": float(np.median([r["rms_card_pct"] for r in rows]))}
    print(f"form error after fitting gamma, delta: median {summary['median_rms_pct']:.1f} %, largest "
          f"{summary['max_rms_pct']:.1f} % RMS (the card's: median {summary['median_rms_card_pct']:.1f} %)")
    if not a.no_results:
        print("wrote", write_results("model_form", {"summary": summary, "cases": rows},
                                     settings={"rpms": list(RPMS), "particles": a.particles, "seed": a.seed,
                                               "card": str(hm.CARD.relative_to(ROOT)), "step_h": STEP_H},
                                     command="python benchmarks/model_form.py"))


if __name__ == "__main__":
    main()
