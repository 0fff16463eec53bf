"""Confirmation set of the moment model: held-out schedules that no fitting choice looked at.

Run:  python benchmarks/moments_confirm.py MODEL.toml [COEFFS.toml ...] [--schedules N]
                                            [--stream K] [--seeds S ...]

Draws N (default 24) random 12 h schedules from a stream that ``bmctl identify`` never uses
(``numpy.random.default_rng([0, 3])``; identify trains on ``[seed, 1]`` and validates on
``[seed, 2]``), runs them on plants seeded 21-23 (M = 4000, like identify's validation) and
prints the mean NRMSE (and its standard error over the schedules) of each coefficient file,
default: the card's own ``models/<card>.moments.toml``. ``--stream 5 --seeds 31 32 33`` gives the
fresh confirmation set. docs/moments.md, Sec. 6, reports both.
About 1 min of plant runs per card on one core.
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

STREAM = 3  # random stream [0, STREAM]: identify trains on [seed, 1] and validates on [seed, 2]
SEEDS = (21, 22, 23)
PARTICLES = 4000


def confirmation_runs(card, schedules: int = 24, stream: int = STREAM, seeds=SEEDS) -> list:
    """Plant-ensemble runs of ``schedules`` random schedules from stream ``[0, stream]``."""
    return ident.run_experiments(card, ident.validation_design(card, 0, schedules, stream), seeds, PARTICLES)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", help="model card (models/*.toml)")
    ap.add_argument("coeffs", nargs="*", help="coefficient files (default: the card's own)")
    ap.add_argument("--schedules", type=int, default=24)
    ap.add_argument("--stream", type=int, default=STREAM,
                    help=f"random stream [0, STREAM] of the schedules (default {STREAM}; 2 is identify's validation)")
    ap.add_argument("--seeds", type=int, nargs="+", default=list(SEEDS), help="plant seeds (default 21 22 23)")
    args = ap.parse_args(argv)
    if args.stream in (1, 2, 4):
        ap.error(f"--stream {args.stream} is one of identify's own streams (1 training, 2 validation, "
                 "4 off-card training); pick another")
    card = load_card(args.model)
    files = args.coeffs or [str(coeffs_path(args.model))]
    t0 = time.time()
    runs = confirmation_runs(card, args.schedules, args.stream, args.seeds)
    print(f"{card.card.name}: {args.schedules} schedules of stream [0, {args.stream}] x {len(args.seeds)} seeds, "
          f"M={PARTICLES} ({time.time() - t0:.0f} s of plant runs)")
    names = ident.MOMENTS[:4]
    print(f"{'coefficients':<48}" + "".join(f"{n:>18}" for n in names))
    for f in files:
        rows = ident.nrmse_table(make_moment_model(card, f), runs)["rows"][:, :4] * 100
        se = rows.std(0, ddof=1) / np.sqrt(len(rows))
        print(f"{Path(f).name:<48}" + "".join(f"{m:9.1f} % ± {s:3.1f}" for m, s in zip(rows.mean(0), se)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
