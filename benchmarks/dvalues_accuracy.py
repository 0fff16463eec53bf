"""Accuracy of the closed-form volume-weighted D-values (moment model, particle filter) against the plant.

The moment model's size law is a log-normal fitted from its number mean and std; its D10/D50/D90
and span are read out in closed form (bmctl.stats.lognormal_size_stats; the particle filter uses
the same function on each particle's state). This benchmark runs the plant ensemble on held-out
random schedules (identify.validation_design, seeds identify.VALID_SEEDS) and prints, per card,
the mean (worst) NRMSE over schedules of

* model:  the moment model's D-values (simulated from the ensemble's initial state) against the
  plant ensemble's sample D-values -- the error a user of `bmctl design` sees;
* law:    the log-normal closed form applied to the plant's *own* mean and std -- the error of the
  size law alone, with perfect moments (the floor for the model and the particle filter);
* weibull: the same with a Weibull law of the plant's mean and std (the particle filter's default
  likelihood law; its volume-weighted quantiles need an incomplete-gamma inverse, so it has no
  casadi closed form) -- printed to tell whether a different two-moment law would do better.

NRMSE as for the moments (identify.nrmse: RMSE over the recorded times / range of the plant-mean
trajectory, floored at 10 % of its mean).

    python benchmarks/dvalues_accuracy.py --schedules 4 --particles 3000 --seeds 2   # ~3 min, small version
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from bmctl.config import load_card
from bmctl.moments import identify as ident
from bmctl.moments.model import make_moment_model
from bmctl.plant import make_plant
from bmctl.stats import lognormal_size_stats
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
    a = ap.parse_args(argv)
    seeds = ident.VALID_SEEDS[: a.seeds]
    print(f"{a.schedules} held-out schedules x {len(seeds)} seeds x M = {a.particles}; NRMSE % mean (worst)")
    print(f"{'card':32s} {'':8s}" + "".join(f"{k:>16s}" for k in KEYS))
    for name in CARDS:
        card = load_card(ROOT / "models" / f"{name}.toml")
        model = make_moment_model(card)
        rows_m, rows_l, rows_w = [], [], []
        for spec in ident.validation_design(card, n=a.schedules):
            Y, D = plant_runs(card, spec, seeds, a.particles)
            P = model.simulate(Y[0], np.array(spec.inputs, dtype=float), ident.DT_H)
            out = model.outputs(P)
            Dm = np.column_stack([out[k] for k in KEYS])
            law = lognormal_size_stats(Y[:, 0], Y[:, 1])
            Dl = np.column_stack([law[k] for k in KEYS])
            rows_m.append(ident.nrmse(Dm, D)), rows_l.append(ident.nrmse(Dl, D))
            rows_w.append(ident.nrmse(weibull_dvalues(Y[:, 0], Y[:, 1]), D))
        for lab, R in (("model", np.array(rows_m)), ("law", np.array(rows_l)), ("weibull", np.array(rows_w))):
            print(f"{name:32s} {lab:8s}" + "".join(f"{100 * m:9.1f} ({100 * w:4.0f})" for m, w in
                                                     zip(R.mean(0), R.max(0))))


if __name__ == "__main__":
    main()
