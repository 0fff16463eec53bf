"""Plant speed: particle-events per second of the numpy and the compiled (numba) engine, side by side.

Run:  python benchmarks/bench_plant.py [--particles 4000 20000] [--hours 12] [--repeat 1]
      [--cards alni-1to1-300rpm-lab] [--engines numpy numba] [--compare DIR]

Prints, for each model card and particle number M, the CPU time of a full run of the card's
recipe (one core; numpy runs single-threaded here; CPU seconds, so that a loaded machine
does not inflate the figures), the simulated particle-events per second (each impact
touches two particles), the real-time factor (milling time / CPU time) and the ratio of each engine's events/s to the first engine's. Both engines run the same seed and must
end in the same state (checked: "same" column: "bits" to the last bit, as docs/performance.md
promises on every CPU; "1e-12" or "no" would be a defect). The compiled code
is loaded (or compiled and cached) before the clock starts.

``--compare DIR`` also runs another checkout's plant (its default engine, in a subprocess,
same card, seeds and schedule) and prints each engine's events/s as a ratio to that one's:
the side-by-side measure of "x times faster than before".
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from bmctl.config import card_schedule, load_card  # noqa: E402
from bmctl.plant.plant import ENGINES, MODELS_DIR, Plant  # noqa: E402

CARDS = ["alni-1to1-300rpm-lab", "alni-1to1-400rpm-fan", "alni-1to3-300rpm-hadjiafxenti"]


def _run(card, engine: str, particles: int, hours: float, seed: int) -> tuple[float, int, Plant]:
    plant = Plant(card, np.random.default_rng(seed), particles, engine=engine)
    t0 = time.process_time()
    plant.run_schedule(card_schedule(card, hours), record_every_h=1.0)
    return time.process_time() - t0, 2 * plant.counts.impacts, plant


_OTHER = """
import json, os, sys, time
sys.path.insert(0, os.getcwd())
import numpy as np
from bmctl.config import card_schedule, load_card
from bmctl.plant.plant import MODELS_DIR, Plant
name, M, hours, repeat = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4])
card = load_card(MODELS_DIR / f"{name}.toml")
best, events = float("inf"), 0
for k in range(repeat):
    plant = Plant(card, np.random.default_rng(k), M)
    t0 = time.process_time()
    plant.run_schedule(card_schedule(card, hours), record_every_h=1.0)
    dt = time.process_time() - t0
    if dt < best:
        best, events = dt, 2 * plant.counts.impacts
print(json.dumps({"cpu_s": best, "events": events}))
"""


def _other_checkout(root: str, name: str, M: int, hours: float, repeat: int) -> tuple[float, float]:
    """CPU seconds and events/s of another checkout's plant (same card, seeds, schedule)."""
    env = dict(os.environ, PYTHONPATH=root)
    out = subprocess.run([sys.executable, "-c", _OTHER, name, str(M), str(hours), str(repeat)], cwd=root,
                         env=env, capture_output=True, text=True, check=True)
    res = json.loads(out.stdout.strip().splitlines()[-1])
    return res["cpu_s"], res["events"] / res["cpu_s"]


def _same(a, b) -> str:
    if all(np.array_equal(x, y) for x, y in zip(a, b)):
        return "bits"
    if all(np.allclose(x, y, rtol=1e-12, atol=0) for x, y in zip(a, b)):
        return "1e-12"
    return "no"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--particles", type=int, nargs="+", default=[4000, 20000])
    ap.add_argument("--hours", type=float, default=12.0)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--cards", nargs="+", default=CARDS[:1], choices=CARDS)
    ap.add_argument("--engines", nargs="+", default=list(ENGINES[::-1]), choices=ENGINES)
    ap.add_argument("--compare", metavar="DIR", help="another checkout (e.g. a git worktree of an older commit)")
    ap.add_argument("--no-results", action="store_true", help="do not write results/bench_plant.json")
    a = ap.parse_args()
    load0 = os.getloadavg()
    record: dict = {"runs": []}
    if "numba" in a.engines:  # load or compile the kernel outside the clock
        from bmctl.plant._compiled import compile_now

        t0 = time.process_time()
        compile_now()
        record["kernel_load_cpu_s"] = time.process_time() - t0
        print(f"compiled kernel loaded in {time.process_time() - t0:.2f} CPU s")
    print(f"{'card':30s} {'M':>6s} {'hours':>5s} {'engine':>6s} {'CPU s':>7s} {'events/s':>10s} "
          f"{'x real time':>11s} {'ratio':>6s} {'same':>5s}" + (f" {'vs DIR':>6s}" if a.compare else ""))
    for name in a.cards:
        card = load_card(MODELS_DIR / f"{name}.toml")
        for M in a.particles:
            rates, finals = {}, {}
            if a.compare:
                other_s, other_rate = _other_checkout(os.path.abspath(a.compare), name, M, a.hours, a.repeat)
                print(f"{name:30s} {M:6d} {a.hours:5.1f} {'DIR':>6s} {other_s:7.2f} {other_rate:10.3g} "
                      f"{a.hours * 3600 / other_s:11.3g}", flush=True)
            for engine in a.engines:
                best, events = np.inf, 0
                for k in range(a.repeat):
                    dt, ev, plant = _run(card, engine, M, a.hours, k)
                    if dt < best:
                        best, events = dt, ev
                    if k == 0:
                        finals[engine] = (plant.s.copy(), plant.r.copy())
                rates[engine] = events / best
                ratio = rates[engine] / rates[a.engines[0]]
                same = _same(finals[engine], finals[a.engines[0]])
                vs = f" {rates[engine] / other_rate:6.2f}" if a.compare else ""
                print(f"{name:30s} {M:6d} {a.hours:5.1f} {engine:>6s} {best:7.2f} {rates[engine]:10.3g} "
                      f"{a.hours * 3600 / best:11.3g} {ratio:6.2f} {same:>5s}{vs}", flush=True)
                record["runs"].append({"card": name, "particles": M, "hours": a.hours, "engine": engine, "cpu_s": best,
                                       "events_per_s": rates[engine], "times_real_time": a.hours * 3600 / best,
                                       "ratio_to_first_engine": ratio, "same_as_first": same,
                                       **({"dir_cpu_s": other_s, "ratio_to_dir": rates[engine] / other_rate}
                                          if a.compare else {})})
    if not a.no_results:
        from bmctl.results import write_results

        record.update(load_average_start=list(load0), load_average_end=list(os.getloadavg()))
        stem = "bench_plant_compare" if a.compare else "bench_plant"
        write_results(stem, record, settings={"particles": a.particles, "hours": a.hours, "repeat": a.repeat,
                                              "cards": a.cards, "engines": a.engines, "compare": bool(a.compare)},
                      command="python benchmarks/bench_plant.py" + (" --compare DIR" if a.compare else ""))


if __name__ == "__main__":
    main()
