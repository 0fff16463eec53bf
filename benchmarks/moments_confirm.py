"""Confirmation set of the moment model: held-out schedules that no fitting choice looked at.

Run:  python benchmarks/moments_confirm.py MODEL.toml [COEFFS.toml ...] [--schedules N]
                                            [--stream K] [--seeds S ...]
      python benchmarks/moments_confirm.py --shipped [--stream K --seeds S ...]

Draws N (default 24) random 12 h schedules from a stream that ``bmctl identify`` never uses
(``numpy.random.default_rng([0, 3])``; identify trains on ``[seed, 1]`` and validates on
``[seed, 2]``), runs them on plants seeded 21-23 (M = 4000, like identify's validation) and
prints the mean NRMSE (and its standard error over the schedules) of each coefficient file,
default: the card's own ``models/<card>.moments.toml``. ``--stream 5 --seeds 31 32 33`` gives the
fresh confirmation set. docs/moments.md, Sec. 6, reports both.
About 1 min of plant runs per card on one core.

``--shipped`` scores every shipped card (``models/*.moments.toml``) on its own coefficients and
writes ``results/moments_confirm.json`` (default stream and seeds) or
``results/moments_confirm_stream<K>.json`` (mean NRMSE in percent, its standard error and the worst
schedule, per card and moment).
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
    ap.add_argument("model", nargs="?", help="model card (models/*.toml)")
    ap.add_argument("coeffs", nargs="*", help="coefficient files (default: the card's own)")
    ap.add_argument("--schedules", type=int, default=24)
    ap.add_argument("--stream", type=int, default=STREAM,
                    help=f"random stream [0, STREAM] of the schedules (default {STREAM}; 2 is identify's validation)")
    ap.add_argument("--seeds", type=int, nargs="+", default=list(SEEDS), help="plant seeds (default 21 22 23)")
    ap.add_argument("--shipped", action="store_true",
                    help="score every shipped card on its own coefficients and write a results file")
    args = ap.parse_args(argv)
    if args.shipped == bool(args.model):
        ap.error("give MODEL.toml or --shipped (not both)")
    if args.stream in (1, 2, 4):
        ap.error(f"--stream {args.stream} is one of identify's own streams (1 training, 2 validation, "
                 "4 off-card training); pick another")
    if args.shipped:
        return shipped(args)
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


def shipped(args) -> int:
    """Every shipped card on its own coefficients; writes the results file."""
    from bmctl.results import write_results

    names = ident.MOMENTS[:4]
    cards = {}
    for path in sorted((ROOT / "models").glob("*.moments.toml")):
        model_path = path.with_name(path.name.removesuffix(".moments.toml") + ".toml")
        card = load_card(model_path)
        t0 = time.time()
        runs = confirmation_runs(card, args.schedules, args.stream, args.seeds)
        rows = ident.nrmse_table(make_moment_model(card, str(path)), runs)["rows"][:, :4] * 100
        se = rows.std(0, ddof=1) / np.sqrt(len(rows))
        cards[card.card.name] = {"mean_pct": dict(zip(names, rows.mean(0))), "se_pct": dict(zip(names, se)),
                                 "max_pct": dict(zip(names, rows.max(0)))}
        print(f"{card.card.name}: " + ", ".join(f"{n} {m:.2f} % ± {s:.2f}" for n, m, s in zip(names, rows.mean(0), se))
              + f" ({time.time() - t0:.0f} s)", flush=True)
    default = args.stream == STREAM and tuple(args.seeds) == SEEDS and args.schedules == 24
    name = "moments_confirm" if default else f"moments_confirm_stream{args.stream}"
    command = "python benchmarks/moments_confirm.py --shipped" + ("" if default else (
        f" --stream {args.stream} --seeds {' '.join(map(str, args.seeds))}"
        + ("" if args.schedules == 24 else f" --schedules {args.schedules}")))
    path = write_results(name, {"cards": cards}, settings={
        "schedules": args.schedules, "stream": [0, args.stream], "seeds": list(args.seeds), "particles": PARTICLES,
        "hours": 12}, command=command)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
