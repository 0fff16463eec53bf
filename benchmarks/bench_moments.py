"""Speed of the moment model: a 12 h prediction, the casadi step and its Jacobian.

Run:  python benchmarks/bench_moments.py [MODEL.toml] [--no-results]

Prints a table of median wall times (ms). Targets: one 12 h prediction <= 5 ms. Writes
results/bench_moments.json (the times, the rate field's casadi instruction count and the load
average before and after) for the default card unless ``--no-results``.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bmctl.moments import make_moment_model  # noqa: E402


def times(fn, repeat: int = 20, warmup: int = 2) -> np.ndarray:
    """Wall times of ``repeat`` calls of ``fn()`` in ms, after ``warmup`` calls."""
    for _ in range(warmup):
        fn()
    ts = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return 1e3 * np.array(ts)


def timeit(fn, repeat: int = 20, warmup: int = 2) -> float:
    """Median wall time of ``fn()`` in ms."""
    return float(np.median(times(fn, repeat, warmup)))


def main(argv=None) -> int:
    import argparse

    import casadi as ca

    default = str(ROOT / "models" / "alni-1to1-300rpm-lab.toml")
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("card", nargs="?", default=default, metavar="MODEL.toml",
                    help="the card whose moment model is timed (default models/alni-1to1-300rpm-lab.toml)")
    ap.add_argument("--no-results", action="store_true", help="print only, do not write results/bench_moments.json")
    a = ap.parse_args(argv)
    no_results, card = a.no_results, a.card
    load_before = os.getloadavg()
    t0 = time.perf_counter()
    model = make_moment_model(card)
    t_build = 1e3 * (time.perf_counter() - t0)
    x0 = model.x0()
    rows = [("build model (card, derived laws)", t_build, "once")]

    for dt in (1.0, 0.5):
        K = int(round(12 / dt))
        U = np.tile([300.0, 1.0], (K, 1))
        t0 = time.perf_counter()
        model.simulate(x0, U, dt)
        rows.append((f"first 12 h prediction, dt {dt:g} h (builds casadi)", 1e3 * (time.perf_counter() - t0), "once"))
        ts = times(lambda: model.simulate(x0, U, dt), 60, 3)
        rows.append((f"12 h prediction, dt {dt:g} h ({K} steps): median of 60", float(np.median(ts)), "<= 5 ms"))
        rows.append((f"12 h prediction, dt {dt:g} h ({K} steps): fastest of 60", float(ts.min()), ""))

    F = model.casadi_step(0.5)
    u, p = np.array([300.0, 1.0]), model.p0()
    rows.append(("casadi step F(x, u, p), dt 0.5 h", timeit(lambda: F(x0, u, p), 50), ""))
    x, us, ps = ca.SX.sym("x", 6), ca.SX.sym("u", 2), ca.SX.sym("p", 2)
    t0 = time.perf_counter()
    J = ca.Function("J", [x, us, ps], [ca.jacobian(F(x, us, ps), ca.vertcat(x, us, ps))])
    rows.append(("build Jacobian dF/d(x, u, p)", 1e3 * (time.perf_counter() - t0), "once"))
    rows.append(("casadi Jacobian dF/d(x, u, p), dt 0.5 h", timeit(lambda: J(x0, u, p), 50), ""))
    xs = np.tile(x0, (1000, 1))
    rows.append(("numpy step, batch of 1000 states, dt 0.5 h", timeit(lambda: model.step(xs, u, 0.5), 5, 1), ""))
    rows.append(("numpy step, one state, dt 0.5 h", timeit(lambda: model.step(x0, u, 0.5), 10), ""))

    w = max(len(r[0]) for r in rows)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    n_ins = model.rate_function().n_instructions()
    print(f"moment model benchmark: {model.card.card.name} ({model.coeffs_source}); "
          f"rate field {n_ins} casadi instructions; load average {load:.2f}")
    print(f"{'case':<{w}}  {'ms':>9}  target")
    for name, ms, target in rows:
        print(f"{name:<{w}}  {ms:9.3f}  {target}")
    if not no_results:
        from bmctl.results import write_results

        ms = {name: value for name, value, _ in rows}
        values = {
            "card": model.card.card.name, "instructions": n_ins,
            "build_ms": ms["build model (card, derived laws)"],
            "first_prediction_ms": ms["first 12 h prediction, dt 0.5 h (builds casadi)"],
            "predict_12h_median_ms": ms["12 h prediction, dt 0.5 h (24 steps): median of 60"],
            "predict_12h_fastest_ms": ms["12 h prediction, dt 0.5 h (24 steps): fastest of 60"],
            "predict_12h_dt1_median_ms": ms["12 h prediction, dt 1 h (12 steps): median of 60"],
            "casadi_step_ms": ms["casadi step F(x, u, p), dt 0.5 h"],
            "casadi_jacobian_ms": ms["casadi Jacobian dF/d(x, u, p), dt 0.5 h"],
            "numpy_batch1000_ms": ms["numpy step, batch of 1000 states, dt 0.5 h"],
            "numpy_one_ms": ms["numpy step, one state, dt 0.5 h"],
            "load_before": list(load_before), "load_after": list(os.getloadavg()),
        }
        same = Path(card).resolve() == Path(default).resolve()
        command = "python benchmarks/bench_moments.py" + ("" if same else f" {card}")
        path = write_results("bench_moments", values, settings={"card": Path(card).name, "repeats_prediction": 60,
                                                                 "dt_h": 0.5, "hours": 12}, command=command)
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
