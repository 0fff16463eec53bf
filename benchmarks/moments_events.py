"""Event rates of the moment model against the plant's event counts on identify's training runs.

Run:  python benchmarks/moments_events.py MODEL.toml [COEFFS.toml ...] [--particles M]

Runs the training design of ``bmctl identify MODEL.toml --seed 0`` (the same experiments,
plant seeds 1-4, M = 4000 by default) and compares, per run, the bonding and fracture events
per particle in each 0.5-h interval that the moment model predicts (``MomentModel.event_counts``,
started from the plant's ensemble mean) with the plant's counts. Prints the mean (and range)
over the milling intervals of ln(model / plant) (+0.01 in both, for near-idle intervals), and
the plant's events per particle-hour. The fit does not see these counts, so the table tests
the rates the trajectories imply. About 2.5 min of plant runs per card on one core.
docs/moments.md, Sec. 6, reports it.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bmctl.config import load_card  # noqa: E402
from bmctl.moments import identify as ident  # noqa: E402
from bmctl.moments.coeffs import coeffs_path  # noqa: E402
from bmctl.moments.model import make_moment_model  # noqa: E402

EPS = 0.01  # events per particle added to both counts before the log ratio


def milling(e) -> np.ndarray:
    """Mask of the intervals of ``e`` with milling (rpm > 0 and a milling share > 0)."""
    return e.U[:, 0] * e.U[:, 1] > 0


def log_ratios(model, e, mill) -> np.ndarray:
    """ln((model + EPS) / (plant + EPS)) of (bonds, fractures) on the intervals ``mill`` of ``e``."""
    C = model.event_counts(e.x0, e.U, e.dt_h, e.p)
    return np.log((C[mill] + EPS) / (e.events[mill] + EPS))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", help="model card (models/*.toml)")
    ap.add_argument("coeffs", nargs="*", help="coefficient files (default: the card's own)")
    ap.add_argument("--particles", type=int, default=4000)
    args = ap.parse_args(argv)
    card = load_card(args.model)
    files = args.coeffs or [str(coeffs_path(args.model))]
    t0 = time.time()
    runs = ident.run_experiments(card, ident.design(card, 0), ident.TRAIN_SEEDS, args.particles)
    print(f"{card.card.name}: {len(runs)} training runs x {len(ident.TRAIN_SEEDS)} seeds, M={args.particles} "
          f"({time.time() - t0:.0f} s of plant runs)")
    for f in files:
        model = make_moment_model(card, f)
        print(f"\n{Path(f).name}: ln(model / plant) per milling interval, mean [min, max]")
        print(f"{'run':<24}{'bonds':>24}{'fractures':>24}{'plant bonds/h':>15}{'fractures/h':>13}")
        allr = []
        for e in runs:
            mill = milling(e)
            lr = log_ratios(model, e, mill)
            if lr.size == 0:
                continue
            allr.append(lr)
            per_h = e.events[mill].sum(0) / (e.dt_h * e.U[mill, 1].sum())
            cells = "".join(f"{v.mean():+10.3f} [{v.min():+.2f}, {v.max():+.2f}]" for v in lr.T)
            print(f"{e.name:<24}{cells}{per_h[0]:15.2f}{per_h[1]:13.2f}")
        A = np.concatenate(allr)
        print(f"{'all intervals':<24}" + "".join(f"{v.mean():+10.3f} (rms {np.sqrt(np.mean(v**2)):.3f})    "
                                                 for v in A.T))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
