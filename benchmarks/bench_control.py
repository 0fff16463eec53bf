"""MPC solve time: median over a short closed loop on the moment model (target <= 100 ms).

Run:  python benchmarks/bench_control.py [--controller controllers/mpc-default.toml] [--hours 4]
                                        [--card alni-1to1-300rpm-lab] [--scenario all] [--method nlp]
      python benchmarks/bench_control.py --compare s_mean_um=30,r_mean=0.05   (all controllers, 12 h)
      python benchmarks/bench_control.py --compiled   (interpreted vs compiled warm solver, side by side)

For each scenario the MPC drives the moment model itself (no plant noise) toward a target
taken from the model's own trajectory under a known schedule (reachable), or from a hotter
schedule under the ceiling (not fully reachable: large residuals, harder for the solver).
Prints per scenario: the cold first solve (exact Hessian; solver construction excluded),
the median wall and CPU time of the warm solves (CPU time is less sensitive to a busy machine),
the 90th percentile / max of the wall times, the iteration counts and the
number of fallbacks, and the final relative target errors. Single-threaded (one core).
``--method nlp`` (default) runs the controller file's settings as the multiple-shooting NLP
(``[plan] method = "nlp"``), ``search`` as the plan on operable schedules, ``file`` as the file says.

The default run (all scenarios, 4 h, mpc-default as the NLP) writes results/bench_control.json,
``--compiled`` (4 h, mpc-default as the NLP) results/bench_control_compiled.json; both record the
load average before and after (timings on a shared machine: the compiled/interpreted ratio,
measured side by side, is the robust number).
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

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


def load(cfg_path: str, method: str = "nlp"):
    """The controller file, its plan method replaced unless ``method == "file"``."""
    cfg = load_controller(cfg_path)
    if method != "file":
        cfg = cfg.model_copy(update={"plan": cfg.plan.model_copy(update={"method": method})})
    return cfg


def run(model, cfg_path: str, scenario: str, hours: float, method: str = "nlp"):
    rpm, mill, ceiling = SCENARIOS[scenario]
    cfg = load(cfg_path, method)
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
cfg = load_controller(sys.argv[2])
cfg = cfg.model_copy(update={"batch_hours": float(sys.argv[3]),
                             "plan": cfg.plan.model_copy(update={"method": "nlp"})})
ctrl = make_controller(cfg, model, json.loads(sys.argv[4]))
ctrl._solver(True)
print(time.perf_counter() - t0)
"""


def _fresh_build(mode: str, model, cfg_path: str, hours: float, target: dict) -> float:  # noqa: D401
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


def compiled_vs_interpreted(model, cfg_path: str, hours: float, write: bool = False) -> None:
    """Warm-solver build (s) and warm-solve CPU (ms), interpreted and compiled, in one run.

    The compiled library is built first if it is not cached (that compile is not timed here);
    the timed build is then what every later process pays: load from the cache.
    """
    from bmctl.control import cache

    rows = {}
    load0 = os.getloadavg()
    for mode in ("0", "wait", "1"):  # interpreted; compile if missing (untimed); cached build (timed)
        os.environ[cache.ENV_SWITCH] = mode
        cfg = load(cfg_path).model_copy(update={"batch_hours": hours})
        rpm, mill, _ = SCENARIOS["reachable-350rpm"]
        K = int(round(hours / cfg.interval_h))
        Xs = model.simulate(model.x0(), [[rpm, mill]] * K, cfg.interval_h)
        target = {"s_mean_um": float(Xs[-1, 0]), "r_mean": float(Xs[-1, 2])}
        ctrl = make_controller(cfg, model, target)
        ctrl.plan(model.x0(), 0.0, None, None)  # cold solve (exact Hessian); compiles with "wait"
        if mode == "wait":
            continue
        build_s = _fresh_build(mode, model, cfg_path, hours, target)
        x, u, cpu, wall, U = model.x0(), None, [], [], []
        for k in range(K):
            plan = ctrl.plan(x, k * cfg.interval_h, None, u)
            if k:
                cpu.append(plan.status.solve_cpu_ms)
                wall.append(plan.status.solve_ms)
            U.append(plan.u[0])
            u = plan.u_apply
            x = model.step(x, u, cfg.interval_h)
        rows["interpreted" if mode == "0" else "compiled"] = (build_s, float(np.median(cpu)), np.array(U),
                                                              float(np.median(wall)))
    (bi, ci, Ui, wi), (bc, cc, Uc, wc) = rows["interpreted"], rows["compiled"]
    load1 = os.getloadavg()
    print(f"load average {load0[0]:.1f} before, {load1[0]:.1f} after")
    print(f"warm solver build in a fresh process (imports included): interpreted {bi:.1f} s, "
          f"compiled (cached) {bc:.2f} s, ratio {bi / bc:.1f}x")
    print(f"warm solve CPU median: interpreted {ci:.0f} ms, compiled {cc:.0f} ms, ratio {ci / cc:.1f}x")
    print(f"warm solve wall median: interpreted {wi:.0f} ms, compiled {wc:.0f} ms, ratio {wi / wc:.1f}x")
    drpm, dmill = float(np.max(np.abs(Ui[:, 0] - Uc[:, 0]))), float(np.max(np.abs(Ui[:, 1] - Uc[:, 1])))
    print(f"first-move plans: max |rpm| difference {drpm:.2g}, max milling difference {dmill:.2g}")
    if write:
        from bmctl.results import write_results

        path = write_results("bench_control_compiled", {
            "interpreted": {"build_s": bi, "warm_cpu_ms": ci, "warm_wall_ms": wi},
            "compiled": {"build_s": bc, "warm_cpu_ms": cc, "warm_wall_ms": wc},
            "ratio": {"build": bi / bc, "warm_cpu": ci / cc, "warm_wall": wi / wc},
            "first_move_max_rpm_diff": drpm, "first_move_max_milling_diff": dmill,
            "load_before": list(load0), "load_after": list(load1), "cpus": os.cpu_count()},
            settings={"controller": os.path.relpath(cfg_path, ROOT), "method": "nlp", "hours": hours,
                      "scenario": "reachable-350rpm", "card": model.card.card.name},
            command="python benchmarks/bench_control.py --compiled")
        print(f"wrote {path}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--controller", default=os.path.join(ROOT, "controllers", "mpc-default.toml"))
    ap.add_argument("--card", default="alni-1to1-300rpm-lab")
    ap.add_argument("--hours", type=float, default=4.0)
    ap.add_argument("--scenario", default="all", choices=["all", *SCENARIOS])
    ap.add_argument("--compare", default=None, metavar="K=V,...",
                    help="instead: run every shipped controller over the batch toward this target")
    ap.add_argument("--compiled", action="store_true", help="instead: interpreted vs compiled warm solver")
    ap.add_argument("--method", default="nlp", choices=["nlp", "search", "file"],
                    help="run the file as the NLP (default), as the plan on operable schedules, or as it says")
    ap.add_argument("--no-results", action="store_true", help="do not write the results file")
    a = ap.parse_args()
    default_run = (a.controller == os.path.join(ROOT, "controllers", "mpc-default.toml") and a.hours == 4.0
                   and a.card == "alni-1to1-300rpm-lab" and a.method == "nlp" and not a.no_results)
    model = make_moment_model(os.path.join(ROOT, "models", f"{a.card}.toml"))
    if a.compiled:
        compiled_vs_interpreted(model, a.controller, a.hours, write=default_run)
        return
    if a.compare:
        from bmctl.control import parse_target

        compare(model, parse_target(a.compare))
        return
    cfg = load(a.controller, a.method)
    load0 = os.getloadavg()
    print(f"{os.path.basename(a.controller)} ({cfg.plan.method}): horizon {cfg.horizon} x {cfg.interval_h:g} h, "
          f"warm Hessian {cfg.solver.hessian} (exact retry {cfg.solver.retry_exact}), {a.hours:g} h closed loop; "
          f"load average {os.getloadavg()[0]:.1f}")
    print(f"{'scenario':22s} {'cold ms':>8s} {'it':>4s} {'median ms':>10s} {'cpu ms':>7s} {'p90 ms':>8s} "
          f"{'max ms':>8s} "
          f"{'median it':>9s} {'fallbacks':>9s} {'exact retries':>13s}  final relative errors")
    all_ms, all_cpu, per = [], [], {}
    names = list(SCENARIOS) if a.scenario == "all" else [a.scenario]
    t0 = time.perf_counter()
    for name in names:
        cold, ms, cpu, its, fb, rt, err = run(model, a.controller, name, a.hours, a.method)
        all_ms += list(ms)
        all_cpu += list(cpu)
        per[name] = {"cold_ms": cold[0], "cold_iterations": cold[1], "median_ms": float(np.median(ms)),
                     "median_cpu_ms": float(np.median(cpu)), "p90_ms": float(np.percentile(ms, 90)),
                     "max_ms": float(ms.max()), "median_iterations": float(np.median(its)), "fallbacks": fb,
                     "exact_retries": rt, "final_error_pct": {k: 100 * v for k, v in err.items()}}
        errs = ", ".join(f"{k} {v:+.1%}" for k, v in err.items())
        print(f"{name:22s} {cold[0]:8.0f} {cold[1]:4d} {np.median(ms):10.0f} {np.median(cpu):7.0f} "
              f"{np.percentile(ms, 90):8.0f} "
              f"{ms.max():8.0f} {np.median(its):9.0f} {fb:9d} {rt:13d}  {errs}")
    print(f"all warm solves: median {np.median(all_ms):.0f} ms wall, {np.median(all_cpu):.0f} ms CPU "
          f"(target <= 100 ms), n = {len(all_ms)}; "
          f"wall {time.perf_counter() - t0:.0f} s")
    if default_run and a.scenario == "all":
        from bmctl.results import write_results

        path = write_results("bench_control", {
            "scenarios": per, "median_ms": float(np.median(all_ms)), "median_cpu_ms": float(np.median(all_cpu)),
            "n_warm": len(all_ms), "load_before": list(load0), "load_after": list(os.getloadavg()),
            "cpus": os.cpu_count()},
            settings={"controller": "controllers/mpc-default.toml", "method": a.method, "hours": a.hours,
                      "card": a.card, "scenarios": {k: {"rpm": v[0], "milling": v[1], "ceiling_c": v[2]}
                                                     for k, v in SCENARIOS.items()},
                      "compiled_cache": os.environ.get("BMCTL_MPC_COMPILE", "default")},
            command="python benchmarks/bench_control.py")
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
