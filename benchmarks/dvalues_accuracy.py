"""Accuracy of the closed-form volume-weighted D-values (moment model, particle filter) against the plant.

The moment model and the particle filter read D-values in closed form from a state's number mean
and std (bmctl.stats.law_size_stats, a Weibull of that mean and std; the filter applies the same
function to each particle). This benchmark runs the plant ensemble on held-out random schedules
(identify.validation_design, seeds identify.VALID_SEEDS) and prints, per card, the mean (worst)
NRMSE over schedules of the plant ensemble's sample D-values against

* model-weibull:   the moment model's outputs (simulated from the ensemble's initial state), the
  error a user of `bmctl design` sees;
* model-lognormal: the same states read through the log-normal (Hatch-Choate) closed form;
* law-weibull:     the closed form applied to the plant's *own* mean and std: the error of the
  law alone with perfect moments (the floor for the model and the particle filter);
* law-lognormal:   the same for the log-normal;
* law-weibull-exact: the exact Weibull (numerical shape, incomplete-gamma inverse) -- the cost of
  the closed form's approximations.

NRMSE as for the moments (identify.nrmse: RMSE over the recorded times / range of the plant-mean
trajectory, floored at 10 % of its mean).

    python benchmarks/dvalues_accuracy.py --schedules 4 --particles 3000 --seeds 2   # ~3 min, small version

Writes ``results/dvalues_accuracy.json``: per card and row, the mean and worst NRMSE (%) of each
D-value over the schedules.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from bmctl.config import load_card
from bmctl.moments import identify as ident
from bmctl.moments.model import make_moment_model
from bmctl.plant import make_plant
from bmctl.stats import law_size_stats, lognormal_size_stats
from scipy import optimize, special

ROOT = Path(__file__).resolve().parents[1]
CARDS = ("alni-1to1-300rpm-lab", "alni-1to1-400rpm-fan", "alni-1to3-300rpm-hadjiafxenti")
KEYS = ("d10_um", "d50_um", "d90_um", "span")


def weibull_dvalues(mean: np.ndarray, std: np.ndarray) -> np.ndarray:
    """Volume-weighted D10, D50, D90 and span of the Weibull law with the given mean and std, (n, 4).

    With u = (s/lambda)^k, s^3 f(s) ds is proportional to u^(3/k) e^(-u) du, so the volume-weighted
    CDF is the regularised incomplete gamma P(1 + 3/k, (s/lambda)^k).
    """
    out = []
    for m, sd in zip(np.atleast_1d(mean), np.atleast_1d(std)):
        cv2 = (sd / m) ** 2
        k = optimize.brentq(lambda k: special.gamma(1 + 2 / k) / special.gamma(1 + 1 / k) ** 2 - 1 - cv2, 0.2, 200.0)
        lam = m / special.gamma(1 + 1 / k)
        d = [lam * special.gammaincinv(1 + 3 / k, q) ** (1 / k) for q in (0.1, 0.5, 0.9)]
        out.append([*d, (d[2] - d[0]) / d[1]])
    return np.array(out)


def plant_runs(card, spec, seeds, particles):
    """Ensemble means over seeds of the model state and the sample D-values after every interval."""
    X, D = [], []
    for sd in seeds:
        plant = make_plant(card, seed=int(sd), particles=particles)
        xs, ds = [], []
        for k in range(len(spec.inputs) + 1):
            m = plant.moments()
            xs.append([m[n] for n in ident.MOMENTS])
            ds.append([m[n] for n in KEYS])
            if k < len(spec.inputs):
                plant.advance(spec.inputs[k][0], ident.DT_H, spec.inputs[k][1])
        X.append(xs), D.append(ds)
    return np.mean(X, axis=0), np.mean(D, axis=0)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--schedules", type=int, default=4)
    ap.add_argument("--particles", type=int, default=3000)
    ap.add_argument("--seeds", type=int, default=2, help="plant seeds per schedule (from identify.VALID_SEEDS)")
    ap.add_argument("--no-results", action="store_true", help="print only")
    a = ap.parse_args(argv)
    seeds = ident.VALID_SEEDS[: a.seeds]
    record = {}
    print(f"{a.schedules} held-out schedules x {len(seeds)} seeds x M = {a.particles}; NRMSE % mean (worst)")
    print(f"{'card':32s} {'':18s}" + "".join(f"{k:>16s}" for k in KEYS))
    for name in CARDS:
        card = load_card(ROOT / "models" / f"{name}.toml")
        model = make_moment_model(card, coeffs="defaults")  # as results/dvalues_accuracy.json was made
        rows: dict[str, list] = {k: [] for k in ("model-weibull", "model-lognormal", "law-weibull", "law-lognormal",
                                                  "law-weibull-exact")}

        def cols(d):
            return np.column_stack([d[k] for k in KEYS])

        for spec in ident.validation_design(card, n=a.schedules):
            Y, D = plant_runs(card, spec, seeds, a.particles)
            P = model.simulate(Y[0], np.array(spec.inputs, dtype=float), ident.DT_H)
            preds = {"model-weibull": cols(model.outputs(P)),
                     "model-lognormal": cols(lognormal_size_stats(P[:, 0], P[:, 1])),
                     "law-weibull": cols(law_size_stats(Y[:, 0], Y[:, 1])),
                     "law-lognormal": cols(lognormal_size_stats(Y[:, 0], Y[:, 1])),
                     "law-weibull-exact": weibull_dvalues(Y[:, 0], Y[:, 1])}
            for k, v in preds.items():
                rows[k].append(ident.nrmse(v, D))
        short = {"alni-1to1-300rpm-lab": "lab", "alni-1to1-400rpm-fan": "400", "alni-1to3-300rpm-hadjiafxenti": "1:3"}
        record[short[name]] = {}
        for lab, R in rows.items():
            R = np.array(R)
            print(f"{name:32s} {lab:18s}" + "".join(f"{100 * m:9.1f} ({100 * w:4.0f})" for m, w in
                                                       zip(R.mean(0), R.max(0))))
            record[short[name]][lab] = {k: {"mean_pct": 100 * float(m), "worst_pct": 100 * float(w)}
                                        for k, m, w in zip(KEYS, R.mean(0), R.max(0))}
    if not a.no_results:
        from bmctl.results import write_results

        write_results("dvalues_accuracy", record,
                      settings={"schedules": a.schedules, "particles": a.particles, "seeds": [int(x) for x in seeds],
                                "dt_h": ident.DT_H},
                      command=f"python benchmarks/dvalues_accuracy.py --schedules {a.schedules} --particles "
                              f"{a.particles} --seeds {a.seeds}")


if __name__ == "__main__":
    main()
