"""Loss weights of the moment-model fit: refit a card's coefficients with other weights per
moment and score them the way ``bmctl identify`` does.

Run:  python benchmarks/moments_weights.py MODEL.toml [--weights 1,1,2,1.5 ...] [--balanced]

Runs the experiments of ``bmctl identify MODEL.toml --seed 0`` (training, held-out, off-card;
the same seeds and M) and the confirmation set of ``benchmarks/moments_confirm.py`` once, about
5 min of plant runs per card on one core (run every time: no file the user names is unpickled).
Then, for each ``--weights`` (s_mean, s_std, r_mean, r_std;
default 1,1,1,1, which reproduces the shipped fit), it fits the identified coefficients from the
built-in defaults like ``identify.fit`` does, and with ``--balanced`` adds a warm-started second
stage whose weights are each moment's in-sample NRMSE over the training runs, divided by their
mean. Prints, per variant, the mean NRMSE on the held-out schedules, the confirmation set and
the off-card check. About 2-4 min of fitting per variant. docs/moments.md, Sec. 6,
reports it.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parent), str(HERE)]

from moments_confirm import PARTICLES, confirmation_runs  # noqa: E402

from bmctl.config import load_card  # noqa: E402
from bmctl.moments import identify as ident  # noqa: E402
from bmctl.moments.model import MomentModel, default_coeffs  # noqa: E402


def experiments(card, train_seeds=ident.TRAIN_SEEDS, n_valid: int = ident.N_VALID) -> dict:
    """identify's training, held-out and off-card runs (seed 0) and the confirmation set."""
    valid_seeds = ident.VALID_SEEDS
    return {
        "train": ident.run_experiments(card, ident.design(card, 0), train_seeds, PARTICLES),
        "held-out": ident.run_experiments(card, ident.validation_design(card, 0, n_valid), valid_seeds, PARTICLES),
        "confirmation": confirmation_runs(card),
        "off-card": ident.run_experiments(card, ident.off_card_design(card), valid_seeds, PARTICLES),
    }


def balance_weights(model, train) -> np.ndarray:
    """Each fitted moment's in-sample NRMSE over the training runs, divided by their mean."""
    n = ident.nrmse_table(model, train)["mean"][list(ident.FIT_IDX)]
    return n / n.mean()


def score(model, runs) -> str:
    cols = []
    for key in ("held-out", "confirmation", "off-card"):
        m = ident.nrmse_table(model, runs[key])["mean"][:4] * 100
        cols.append(", ".join(f"{v:.2f}" for v in m) if key != "off-card" else f"{m.mean():.2f}")
    return " / ".join(cols)


def parse_weights(text: str) -> tuple[float, ...]:
    try:
        w = tuple(float(v) for v in text.split(","))
    except ValueError:
        w = ()
    if len(w) != 4 or not all(np.isfinite(w)) or min(w) <= 0:
        raise argparse.ArgumentTypeError(f"need 4 positive numbers, got {text!r}")
    return w


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", help="model card (models/*.toml)")
    ap.add_argument("--weights", type=parse_weights, action="append",
                    help="weights of s_mean, s_std, r_mean, r_std (repeatable; default 1,1,1,1)")
    ap.add_argument("--balanced", action="store_true", help="add the balanced second stage to each fit")
    ap.add_argument("--train-seeds", type=int, nargs="+", default=list(ident.TRAIN_SEEDS),
                    help=f"training plant seeds (default {' '.join(map(str, ident.TRAIN_SEEDS))}; "
                         "the two-seed table: 1 2)")
    ap.add_argument("--valid-schedules", type=int, default=ident.N_VALID,
                    help=f"held-out schedules (default {ident.N_VALID}; the published table: 24)")
    args = ap.parse_args(argv)
    card = load_card(args.model)
    t0 = time.time()
    runs = experiments(card, args.train_seeds, args.valid_schedules)
    print(f"{card.card.name}: plant runs ready ({time.time() - t0:.0f} s); mean NRMSE %, s_mean, s_std, "
          "r_mean, r_std: held-out / confirmation / off-card mean of 8")
    model0 = MomentModel(card, default_coeffs(card), "defaults")
    for w in args.weights or [(1.0, 1.0, 1.0, 1.0)]:
        res = ident.fit(model0, runs["train"], weights=w)
        model = MomentModel(card, res.coeffs, "fit")
        print(f"weights {w}: {score(model, runs)}  (cost {res.cost:.4g}, {res.nfev} evaluations)", flush=True)
        if args.balanced:
            wb = balance_weights(model, runs["train"])
            res = ident.fit(model, runs["train"], weights=tuple(wb))
            model = MomentModel(card, res.coeffs, "balanced")
            print(f"  balanced {np.round(wb, 3)}: {score(model, runs)}  ({res.nfev} evaluations)", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
