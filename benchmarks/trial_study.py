"""Closed-loop evidence: run trial scenarios over seeds and tabulate final errors, heat and solver health.

Run:  python benchmarks/trial_study.py --seeds 10 scenarios/trial-mismatch.toml \
          scenarios/trial-mismatch-recipe.toml scenarios/trial-mismatch-lqr.toml [--out out/study]

Each (scenario, seed) runs `bmctl.trial.run_trial` into OUT/<scenario>/seed<N>. A finished run is
reused and an interrupted one resumed only if nothing it depends on changed: the fingerprint (sha256
of the scenario, of every file under models/ and controllers/ and of the bmctl sources) is stored
next to it, and a run with another fingerprint is started afresh. Prints a markdown table: final
relative error per target (mean, sd, max over seeds), peak vial temperature, temperature violations,
fallbacks, solver failures, median MPC solve time and wall time per trial.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from bmctl.trial import run_trial  # noqa: E402


ROOT = Path(__file__).resolve().parents[1]


def fingerprint(scenario: str) -> str:
    """sha256 of the scenario file, of every model card, coefficient file and controller config, and of
    the bmctl sources (a code change must not reuse results of the old code)."""
    h = hashlib.sha256(Path(scenario).read_bytes())
    files = [f for folder in ("models", "controllers") for f in sorted((ROOT / folder).glob("*.toml"))]
    files += sorted((ROOT / "bmctl").rglob("*.py"))
    for f in files:
        h.update(str(f.relative_to(ROOT)).encode() + b"\0" + f.read_bytes())
    return h.hexdigest()[:16]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenarios", nargs="+")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--out", default="out/study")
    a = ap.parse_args()
    rows = []
    for sc in a.scenarios:
        name = Path(sc).stem
        sums, walls = [], []
        fp = fingerprint(sc)
        for seed in range(a.first_seed, a.first_seed + a.seeds):
            out = Path(a.out) / name / f"seed{seed}"
            stamp = out / "fingerprint.txt"
            if out.exists() and (not stamp.exists() or stamp.read_text().strip() != fp):
                shutil.rmtree(out)  # made with other models or configs: start afresh
            out.mkdir(parents=True, exist_ok=True)
            stamp.write_text(fp + "\n")
            t0 = time.perf_counter()
            if (out / "summary.json").exists():
                s = json.loads((out / "summary.json").read_text())
            else:
                s = run_trial(sc, out, seed=seed, resume=(out / "checkpoint.npz").exists())
                walls.append(time.perf_counter() - t0)
            sums.append(s)
            print(f"{name} seed {seed}: err {s['final_error']} Tmax {s['max_temperature_c']:.1f} "
                  f"viol {s['temperature_violations']} fb {s['fallbacks']}", flush=True)
        errs = {k: np.array([s["final_error"][k] for s in sums]) for k in sums[0]["final_error"]}
        rows.append((name, errs, max(s["max_temperature_c"] for s in sums), sum(s["temperature_violations"] for s in sums),
                     sum(s["fallbacks"] for s in sums), sum(s["solver_failures"] for s in sums),
                     float(np.median([s["median_solve_ms"] for s in sums])), float(np.mean(walls)) if walls else float("nan"),
                     len(sums)))
    print()
    print("| scenario | seeds | final error (mean ± sd, max) | max T (°C) | T violations | fallbacks | solver failures | median solve (ms) | wall per trial (s) |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for name, errs, tmax, viol, fb, fail, solve, wall, n in rows:
        e = "; ".join(f"{k} {v.mean():.1%} ± {v.std():.1%}, max {v.max():.1%}" for k, v in errs.items()) or "—"
        print(f"| {name} | {n} | {e} | {tmax:.1f} | {viol} | {fb} | {fail} | {solve:.0f} | {wall:.0f} |")


if __name__ == "__main__":
    main()
