"""MPC solve time: median over a short closed loop on the moment model (target <= 100 ms).

Run:  python benchmarks/bench_control.py [--controller controllers/mpc-default.toml] [--hours 4]
                                        [--card alni-1to1-300rpm-lab] [--scenario all]
      python benchmarks/bench_control.py --compare s_mean_um=30,r_mean=0.05   (all controllers, 12 h)
      python benchmarks/bench_control.py --compiled   (interpreted vs compiled warm solver, side by side)

For each scenario the MPC drives the moment model itself (no plant noise) toward a target
taken from the model's own trajectory under a known schedule (reachable), or from a hotter
schedule under the ceiling (not fully reachable: large residuals, harder for the solver).
Prints per scenario: the cold first solve (exact Hessian; solver construction excluded),
the median wall and CPU time of the warm solves (CPU time is less sensitive to a busy machine),
the 90th percentile / max of the wall times, the iteration counts and the
number of fallbacks, and the final relative target errors. Single-threaded (one core).

The default run writes ``results/bench_control.json``, ``--compiled`` writes
``results/bench_control_compiled.json``, ``--nlp`` writes ``results/bench_control_nlp.json`` (each
with the load average; ``--no-results``: none). ``controllers/mpc-default.toml`` plans by search
(``[plan] method = "search"``); ``--nlp`` and ``--compiled`` time its multiple-shooting NLP instead.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))  # this checkout's bmctl
from bmctl.control import make_controller  # noqa: E402
from bmctl.control.config import load_controller  # noqa: E402
from bmctl.moments.model import make_moment_model  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: name -> (schedule rpm, milling, ceiling C): the target is the model state after --hours of it
SCENARIOS = {
    "reachable-350rpm": (350.0, 0.8, 80.0),
    "reachable-250rpm": (250.0, 1.0, 80.0),
    "ceiling-bound-400rpm": (400.0, 1.0, 60.0),
}


def _load(cfg_path: str, nlp: bool):
    """The controller config; with ``nlp`` its [plan] method set to the multiple-shooting NLP."""
    cfg = load_controller(cfg_path)
    if nlp and hasattr(cfg, "plan"):
        cfg = cfg.model_copy(update={"plan": cfg.plan.model_copy(update={"method": "nlp"})})
    return cfg


def run(model, cfg_path: str, scenario: str, hours: float, nlp: bool = False):
    rpm, mill, ceiling = SCENARIOS[scenario]
    cfg = _load(cfg_path, nlp)
    dt = cfg.interval_h
    K = int(round(hours / dt))
    Xs = model.simulate(model.x0(), [[rpm, mill]] * K, dt)
    target = {"s_mean_um": float(Xs[-1, 0]), "r_mean": float(Xs[-1, 2])}
    cfg = cfg.model_copy(update={"batch_hours": hours,
                                 "temperature": cfg.temperature.model_copy(update={"ceiling_c": ceiling})})
    ctrl = make_controller(cfg, model, target)
    x, u = model.x0(), None
    ms, cpu, its, fb, retried = [], [], [], 0, 0
    cold = None
    for k in range(K):
        plan = ctrl.plan(x, k * dt, None, u)
        st = plan.status
        if k == 0:
            cold = (st.solve_ms, st.iterations)
        else:
            ms.append(st.solve_ms)
            cpu.append(st.solve_cpu_ms)
            its.append(st.iterations)
        fb += st.fallback != "none"
        retried += "retried" in st.reason
        u = plan.u_apply
        x = model.step(x, u, dt)
    err = {k: x[["s_mean_um", "s_std_um", "r_mean", "r_std"].index(k)] / v - 1 for k, v in target.items()}
    return cold, np.array(ms), np.array(cpu), np.array(its), fb, retried, err


COMPARE = ["mpc-default", "mpc-fast", "lqr-baseline", "recipe-300rpm-continuous", "recipe-400rpm-30-10"]


def compare(model, target: dict) -> None:
    """Every shipped controller in closed loop on the moment model over the card's batch."""
    from bmctl.control.base import interval_peaks

    c = model.const
    tg = ", ".join(f"{k} = {v:g}" for k, v in target.items())
    print(f"closed loop on the moment model, target {tg}")
    print(f"{'controller':26s} {'s_mean':>7s} {'r_mean':>7s} {'s_std':>6s} {'mill h':>7s} {'kWh':>6s} "
          f"{'peak T':>7s} {'median ms':>9s} {'fallbacks':>9s}")
    for name in COMPARE:
        ctrl = make_controller(os.path.join(ROOT, "controllers", f"{name}.toml"), model, target)
        dt = ctrl.interval_h
        x, u, t, X, U, ms, fb = model.x0(), None, 0.0, [model.x0()], [], [], 0
        while t < ctrl.t_end_h - 1e-9:
            plan = ctrl.plan(x, t, None, u)
            u = plan.u_apply
            U.append(u)
            ms.append(plan.status.solve_ms)
            fb += plan.status.fallback != "none"
            x = model.step(x, u, dt)
            X.append(x)
            t += dt
        X, U = np.array(X), np.array(U)
        energy = np.sum(c.power_max_W * (U[:, 0] / c.rpm_max) ** 3 * U[:, 1] * dt) / 1000
        print(f"{name:26s} {x[0]:7.2f} {x[2]:7.4f} {x[1]:6.2f} {U[:, 1].sum() * dt:7.2f} {energy:6.3f} "
              f"{interval_peaks(model, X, U, dt).max():7.1f} {np.median(ms[1:] or ms):9.0f} {fb:9d}")


_FRESH_BUILD = """
import json, os, sys, time
t0 = time.perf_counter()
from bmctl.control import make_controller
from bmctl.control.config import load_controller
from bmctl.moments.model import make_moment_model
model = make_moment_model(sys.argv[1])
cfg = load_controller(sys.argv[2]).model_copy(update={"batch_hours": float(sys.argv[3])})
cfg = cfg.model_copy(update={"plan": cfg.plan.model_copy(update={"method": "nlp"})})
ctrl = make_controller(cfg, model, json.loads(sys.argv[4]))
ctrl._solver(True)
print(time.perf_counter() - t0)
"""


def _fresh_build(mode: str, model, cfg_path: str, hours: float, target: dict) -> float:
    """Seconds a fresh process takes from start to a built warm solver (imports included)."""
    import json
    import subprocess
    import sys

    from bmctl.control import cache

    card = os.path.join(ROOT, "models", f"{model.card.card.name}.toml")
    env = dict(os.environ, **{cache.ENV_SWITCH: mode})
    out = subprocess.run([sys.executable, "-c", _FRESH_BUILD, card, cfg_path, str(hours), json.dumps(target)],
                         env=env, cwd=ROOT, capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def _libraries() -> set:
    from bmctl.control import cache

    folder = cache.cache_dir()
    return set(folder.glob("*.so")) if folder is not None and folder.is_dir() else set()


def compiled_vs_interpreted(model, cfg_path: str, hours: float) -> dict:
    """Warm-solver build (s) and warm-solve CPU (ms), interpreted and compiled, in one run.

    The compiled library is built first if it is not cached (that compile is not timed here);
    the timed build is then what every later process pays: load from the cache.
    """
    from bmctl.control import cache

    rows, record = {}, {}
    for mode in ("0", "wait", "1"):  # interpreted; compile if missing (untimed); cached build (timed)
        os.environ[cache.ENV_SWITCH] = mode
        cfg = _load(cfg_path, True).model_copy(update={"batch_hours": hours})
        rpm, mill, _ = SCENARIOS["reachable-350rpm"]
        K = int(round(hours / cfg.interval_h))
        Xs = model.simulate(model.x0(), [[rpm, mill]] * K, cfg.interval_h)
        target = {"s_mean_um": float(Xs[-1, 0]), "r_mean": float(Xs[-1, 2])}
        ctrl = make_controller(cfg, model, target)
        before, t0 = _libraries(), time.perf_counter()
        cold = ctrl.plan(model.x0(), 0.0, None, None)  # cold solve (exact Hessian); compiles with "wait"
        if mode == "wait":
            record["compile"] = {"wall_s": time.perf_counter() - t0, "libraries_built": len(_libraries() - before)}
            continue
        record["interpreted" if mode == "0" else "compiled"] = {"cold_solve_ms": cold.status.solve_ms}
        build_s = _fresh_build(mode, model, cfg_path, hours, target)
        x, u, cpu, U = model.x0(), None, [], []
        for k in range(K):
            plan = ctrl.plan(x, k * cfg.interval_h, None, u)
            if k:
                cpu.append(plan.status.solve_cpu_ms)
            U.append(plan.u[0])
            u = plan.u_apply
            x = model.step(x, u, cfg.interval_h)
        rows["interpreted" if mode == "0" else "compiled"] = (build_s, float(np.median(cpu)), np.array(U))
    (bi, ci, Ui), (bc, cc, Uc) = rows["interpreted"], rows["compiled"]
    record["interpreted"].update(build_s=bi, warm_cpu_median_ms=ci)
    record["compiled"].update(build_s=bc, warm_cpu_median_ms=cc)
    record.update(build_ratio=bi / bc, warm_cpu_ratio=ci / cc,
                  cold_ratio=record["interpreted"]["cold_solve_ms"] / record["compiled"]["cold_solve_ms"],
                  max_rpm_difference=float(np.max(np.abs(Ui[:, 0] - Uc[:, 0]))),
                  max_milling_difference=float(np.max(np.abs(Ui[:, 1] - Uc[:, 1]))))
    if record["compile"]["libraries_built"]:
        print(f"compiled {record['compile']['libraries_built']} libraries in {record['compile']['wall_s']:.0f} s")
    print(f"cold solve: interpreted {record['interpreted']['cold_solve_ms']:.0f} ms, "
          f"compiled {record['compiled']['cold_solve_ms']:.0f} ms")
    print(f"load average {os.getloadavg()[0]:.1f}")
    print(f"warm solver build in a fresh process (imports included): interpreted {bi:.1f} s, "
          f"compiled (cached) {bc:.2f} s, ratio {bi / bc:.1f}x")
    print(f"warm solve CPU median: interpreted {ci:.0f} ms, compiled {cc:.0f} ms, ratio {ci / cc:.1f}x")
    print(f"first-move plans: max |rpm| difference {np.max(np.abs(Ui[:, 0] - Uc[:, 0])):.2g}, "
          f"max milling difference {np.max(np.abs(Ui[:, 1] - Uc[:, 1])):.2g}")
    return record


def _write(stem: str, record: dict, load0, a, extra: str = "") -> None:
    from bmctl.results import write_results

    record.update(load_average_start=list(load0), load_average_end=list(os.getloadavg()), cpus=os.cpu_count())
    args = "" if a.hours == 4.0 else f" --hours {a.hours:g}"
    write_results(stem, record, settings={"controller": os.path.relpath(a.controller, ROOT), "card": a.card,
                                          "hours": a.hours, "scenario": a.scenario,
                                          "method": "nlp" if a.nlp or a.compiled else "as configured"},
                  command="python benchmarks/bench_control.py" + extra + args)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--controller", default=os.path.join(ROOT, "controllers", "mpc-default.toml"))
    ap.add_argument("--card", default="alni-1to1-300rpm-lab")
    ap.add_argument("--hours", type=float, default=4.0)
    ap.add_argument("--scenario", default="all", choices=["all", *SCENARIOS])
    ap.add_argument("--compare", default=None, metavar="K=V,...",
                    help="instead: run every shipped controller over the batch toward this target")
    ap.add_argument("--compiled", action="store_true", help="instead: interpreted vs compiled warm solver")
    ap.add_argument("--nlp", action="store_true",
                    help='the multiple-shooting NLP (IPOPT) even where the file says [plan] method = "search"')
    ap.add_argument("--no-results", action="store_true", help="write no results file")
    a = ap.parse_args()
    load0 = os.getloadavg()
    model = make_moment_model(os.path.join(ROOT, "models", f"{a.card}.toml"))
    if a.compiled:
        record = compiled_vs_interpreted(model, a.controller, a.hours)
        if not a.no_results:
            _write("bench_control_compiled", record, load0, a, " --compiled")
        return
    if a.compare:
        from bmctl.control import parse_target

        compare(model, parse_target(a.compare))
        return
    cfg = _load(a.controller, a.nlp)
    print(f"{os.path.basename(a.controller)} ({'nlp' if a.nlp or not hasattr(cfg, 'plan') else cfg.plan.method}): horizon {cfg.horizon} x {cfg.interval_h:g} h, "
          f"warm Hessian {cfg.solver.hessian} (exact retry {cfg.solver.retry_exact}), {a.hours:g} h closed loop; "
          f"load average {os.getloadavg()[0]:.1f}")
    print(f"{'scenario':22s} {'cold ms':>8s} {'it':>4s} {'median ms':>10s} {'cpu ms':>7s} {'p90 ms':>8s} "
          f"{'max ms':>8s} "
          f"{'median it':>9s} {'fallbacks':>9s} {'exact retries':>13s}  final relative errors")
    all_ms, all_cpu, record = [], [], {"scenarios": {}}
    names = list(SCENARIOS) if a.scenario == "all" else [a.scenario]
    t0 = time.perf_counter()
    for name in names:
        cold, ms, cpu, its, fb, rt, err = run(model, a.controller, name, a.hours, a.nlp)
        all_ms += list(ms)
        all_cpu += list(cpu)
        errs = ", ".join(f"{k} {v:+.1%}" for k, v in err.items())
        record["scenarios"][name] = {"cold_ms": cold[0], "cold_iterations": cold[1], "median_ms": np.median(ms),
                                     "median_cpu_ms": np.median(cpu), "p90_ms": np.percentile(ms, 90),
                                     "max_ms": ms.max(), "median_iterations": np.median(its), "fallbacks": fb,
                                     "exact_retries": rt, "warm_solves": len(ms)}
        print(f"{name:22s} {cold[0]:8.0f} {cold[1]:4d} {np.median(ms):10.0f} {np.median(cpu):7.0f} "
              f"{np.percentile(ms, 90):8.0f} "
              f"{ms.max():8.0f} {np.median(its):9.0f} {fb:9d} {rt:13d}  {errs}")
    print(f"all warm solves: median {np.median(all_ms):.0f} ms wall, {np.median(all_cpu):.0f} ms CPU "
          f"(target <= 100 ms), n = {len(all_ms)}; "
          f"wall {time.perf_counter() - t0:.0f} s")
    if not a.no_results and not a.compare:
        record.update(median_ms=np.median(all_ms), median_cpu_ms=np.median(all_cpu), warm_solves=len(all_ms),
                      wall_s=time.perf_counter() - t0, libraries_cached=len(_libraries()))
        _write("bench_control_nlp" if a.nlp else "bench_control", record, load0, a, " --nlp" if a.nlp else "")


if __name__ == "__main__":
    main()
