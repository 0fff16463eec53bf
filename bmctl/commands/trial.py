"""Closed-loop trial: stochastic plant, micrograph sampling, particle filter and controller."""

from __future__ import annotations

import sys
from pathlib import Path

from ..errors import InputError
from ._args import int_arg, output_path




def configure(p):
    p.add_argument("scenario", metavar="SCENARIO.toml", help="trial definition (see scenarios/trial-*.toml)")
    p.add_argument("--seed", type=int_arg("--seed", 0), default=0, help="random seed (default 0)")
    p.add_argument("--out", default=None, metavar="DIR", help="output folder (default out/trial-<name>-seed<N>)")
    p.add_argument("--resume", default=None, metavar="DIR", help="carry on an interrupted trial in DIR")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args) -> int:
    from ..scenario import load_scenario
    from ..trial import run_trial

    sc = load_scenario(args.scenario)
    if args.resume and args.out and Path(args.resume) != Path(args.out):
        raise InputError("--resume: give the trial folder once (--resume DIR), not with a different --out")
    out = output_path(args.resume or args.out or f"out/trial-{sc.scenario.name}-seed{args.seed}",
                      "--resume" if args.resume else "--out")
    bar = None
    if not args.no_progress:
        from tqdm import tqdm

        bar = tqdm(total=None, unit="step", desc=sc.scenario.name, leave=False, file=sys.stderr)

    def progress(k, K):
        if bar is not None:
            bar.total = K
            bar.update(k - bar.n)
    try:
        summary = run_trial(args.scenario, out, seed=args.seed, resume=args.resume is not None, progress=progress)
    finally:
        if bar is not None:
            bar.close()
    err = ", ".join(f"{k} {v:.1%}" for k, v in summary["final_error"].items()) or "(no target)"
    print(f"{sc.scenario.name} seed {args.seed}: final error {err}; max T {summary['max_temperature_c']:.1f} C, "
          f"{summary['temperature_violations']} violations; energy {summary['energy_kj']:.0f} kJ; "
          f"{summary['fallbacks']} fallbacks; median solve {summary['median_solve_ms']:.0f} ms")
    print(f"  wrote {out}/trajectory.csv, summary.json, trial.png")
    return 0
