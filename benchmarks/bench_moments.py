"""Speed of the moment model: a 12 h prediction, the casadi step and its Jacobian.

Run:  python benchmarks/bench_moments.py [MODEL.toml] [--no-results]

Prints a table of median wall times (ms) and writes them with the load average to
``results/bench_moments.json`` (keys in ``KEYS``). Targets: one 12 h prediction <= 5 ms.
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


#: results-file key of each printed row, in order
KEYS = ("build_ms", "first_predict_dt1_ms", "predict_dt1_median_ms", "predict_dt1_fastest_ms",
        "first_predict_dt05_ms", "predict_dt05_median_ms", "predict_dt05_fastest_ms", "casadi_step_ms",
        "jacobian_build_ms", "casadi_jacobian_ms", "numpy_step_batch1000_ms", "numpy_step_one_ms")


def main(argv=None) -> int:
    import casadi as ca

    argv = sys.argv[1:] if argv is None else list(argv)
    no_results = "--no-results" in argv
    argv = [a for a in argv if a != "--no-results"]
    card = argv[0] if argv else str(ROOT / "models" / "alni-1to1-300rpm-lab.toml")
    load0 = os.getloadavg()
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

        values = {key: row[1] for key, row in zip(KEYS, rows)}
        values.update(rate_field_instructions=n_ins, load_average_start=list(load0),
                      load_average_end=list(os.getloadavg()), cpus=os.cpu_count())
        shown = "" if not argv else " " + os.path.relpath(card, ROOT)
        write_results("bench_moments", values, settings={"card": model.card.card.name, "repeat": 60,
                                                          "coefficients": os.path.relpath(str(model.coeffs_source), ROOT)},
                      command="python benchmarks/bench_moments.py" + shown)
    return 0


if __name__ == "__main__":
    sys.exit(main())
