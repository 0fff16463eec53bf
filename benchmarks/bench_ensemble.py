"""Wall time of a ``bmctl whatif`` ensemble of 64 plants on 1 and 2 workers (and the ratio).

1 worker is the serial in-process path (no Dask); n >= 2 is a local Dask cluster of n worker
processes (:func:`bmctl.parallel.client_for`). Starting the cluster (processes, imports) is
timed apart from the ensemble. Both must give the same numbers; the script checks it.

    python benchmarks/bench_ensemble.py                          # 64 plants, M = 1000, 1 h at 300 rpm
    python benchmarks/bench_ensemble.py --particles 500 --hours 0.5 --workers 1 2 4
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bmctl.config import load_card  # noqa: E402
from bmctl.parallel import client_for, close_client  # noqa: E402
from bmctl.whatif import run_schedule_ensemble  # noqa: E402

CARD = Path(__file__).resolve().parents[1] / "models" / "alni-1to1-300rpm-lab.toml"


def _warm(card_path: str) -> None:
    from bmctl.plant import make_plant

    make_plant(card_path, seed=0, particles=100).advance(300.0, 0.01)


def timed(card, segs, seeds, particles, workers):
    """(seconds to start the engine, seconds of the ensemble, result)."""
    t0 = time.perf_counter()
    client = client_for(None, workers)
    if client is not None:  # every worker imports bmctl and loads the compiled plant before the clock
        client.run(_warm, str(CARD))
    t1 = time.perf_counter()
    try:
        res = run_schedule_ensemble(card, "bench", segs, seeds, particles, base_seed=1, client=client)
    finally:
        close_client(client)
    return t1 - t0, time.perf_counter() - t1, res


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=64)
    ap.add_argument("--particles", type=int, default=1000)
    ap.add_argument("--hours", type=float, default=1.0)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--no-results", action="store_true", help="do not write results/bench_ensemble*.json")
    a = ap.parse_args()
    load0 = os.getloadavg()
    rows = []
    card = load_card(CARD)
    segs = [(a.hours, 300.0)]
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs; {a.seeds} plants, M = {a.particles}, "
          f"{a.hours:g} h at 300 rpm")
    base = None
    for w in a.workers:
        start_s, run_s, res = timed(card, segs, a.seeds, a.particles, w)
        if base is None:
            base = (run_s, res)
        same = all(np.array_equal(res.traj[k], base[1].traj[k]) for k in res.traj)
        print(f"  {w} worker{'s' if w > 1 else ' '}: start {start_s:5.1f} s, ensemble {run_s:6.1f} s, "
              f"speed-up {base[0] / run_s:4.2f}x; same numbers as {a.workers[0]} worker: {same}")
        rows.append({"workers": w, "start_s": start_s, "ensemble_s": run_s, "speedup": base[0] / run_s, "same": bool(same)})
    if not a.no_results:
        from bmctl.results import write_results

        default = (a.particles, a.hours) == (1000, 1.0)
        stem = "bench_ensemble" if default else f"bench_ensemble_m{a.particles}_h{a.hours:g}".replace(".", "p")
        write_results(stem, {"runs": rows, "load_average_start": list(load0), "load_average_end": list(os.getloadavg())},
                      settings={"seeds": a.seeds, "particles": a.particles, "hours": a.hours, "workers": a.workers},
                      command="python benchmarks/bench_ensemble.py" + ("" if default else
                                                                      f" --particles {a.particles} --hours {a.hours:g}"))


if __name__ == "__main__":
    main()
