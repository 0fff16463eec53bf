"""Verify the plant's Monte Carlo engine: analytic population balances, the one-collision reference, bookkeeping.

Prints the verification table (check, case, M, quantity, error, expected Monte Carlo
error, pass/fail) and writes, into ``--out``: ``verification.txt`` (the table),
``verification.csv``, ``analytic.png`` (exact vs simulated distributions) and
``reference.png`` (plant vs reference). Exit status 0 when every check passes, 1 when
one fails, 2 on bad input. See docs/verification.md.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from ..errors import InputError
from ._args import int_arg, output_path, shipped


def configure(p):
    p.add_argument("--quick", action="store_true",
                   help="smaller runs: M up to 8000, fewer seeds, 12 h bookkeeping (about 20 s instead of 3 min)")
    p.add_argument("--out", default="out/verify", metavar="DIR", help="output folder (default out/verify)")
    p.add_argument("--seed", type=int_arg("--seed", 0), default=0, help="first seed (default 0)")
    p.add_argument("--models", nargs="+", default=None, metavar="MODEL.toml",
                   help="model cards for the reference and bookkeeping checks (default: the cards in models/)")
    p.add_argument("--no-progress", action="store_true", help="no progress lines on stderr")


def default_cards() -> list[Path]:
    """The shipped model cards (``NAME.toml`` in ``models/``; companion files such as
    ``NAME.moments.toml`` left out), or :class:`InputError` naming ``--models`` where the
    installation has none."""
    folder = shipped("models", "--models")
    cards = sorted(p for p in folder.glob("*.toml") if p.suffixes == [".toml"])
    if not cards:
        raise InputError(f"--models: no model cards given and none found in {folder}")
    return cards


def run(args) -> int:
    from .. import io
    from ..validation import verify as V
    from ..config import load_card

    out = output_path(args.out)
    paths = [Path(p) for p in args.models] if args.models else default_cards()
    cards = []
    for p in paths:
        try:
            cards.append(load_card(p))
        except InputError as exc:
            raise InputError(f"--models: {exc}") from None
    settings = V.QUICK if args.quick else V.FULL
    t0 = time.time()

    def progress(msg: str) -> None:
        if not args.no_progress:
            print(f"  [{time.time() - t0:5.0f} s] {msg}", file=sys.stderr, flush=True)

    report = V.run_all(settings, args.seed, cards, progress)
    table = V.rows(report)
    text = V.format_table(table)
    tests = [r for r in table if r[-1] != "info"]
    failed = [r for r in tests if r[-1] == "FAIL"]
    summary = (f"{len(tests) - len(failed)} of {len(tests)} checks passed"
               f" ({'quick' if args.quick else 'full'}, seed {args.seed}, {time.time() - t0:.0f} s)")
    with io.output_set():  # the table and the figures, or none of them
        io.write_text(out / "verification.txt", text + "\n\n" + summary + "\n")
        io.write_csv(out / "verification.csv", V.HEADER, table)
        V.analytic_figure(report, out / "analytic.png")
        V.reference_figure(report, out / "reference.png")
    print(text)
    print()
    print(summary)
    for name in ("verification.txt", "verification.csv", "analytic.png", "reference.png"):
        print(f"  wrote {out / name}")
    return 1 if failed else 0
