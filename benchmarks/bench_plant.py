"""Plant speed: particle-events per second and the real-time factor.

Run:  python benchmarks/bench_plant.py [--particles 20000] [--hours 12] [--repeat 3]

Prints, for each model card, the best wall time of a full run of the card's recipe
(one CPU core; numpy runs single-threaded here), the simulated particle-events per
second (each impact touches two particles) and the real-time factor
(milling time / wall time).
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from bmctl.config import card_schedule, load_card  # noqa: E402
from bmctl.plant.plant import MODELS_DIR, Plant  # noqa: E402

CARDS = ["alni-1to1-300rpm-lab", "alni-1to1-400rpm-fan", "alni-1to3-300rpm-hadjiafxenti"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--particles", type=int, default=20000)
    ap.add_argument("--hours", type=float, default=12.0)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    print(f"{'card':32s} {'M':>6s} {'hours':>5s} {'wall s':>7s} {'events/s':>10s} {'x real time':>11s}")
    for name in CARDS:
        card = load_card(MODELS_DIR / f"{name}.toml")
        best, events = np.inf, 0
        for k in range(a.repeat):
            plant = Plant(card, np.random.default_rng(k), a.particles)
            t0 = time.perf_counter()
            plant.run_schedule(card_schedule(card, a.hours), record_every_h=1.0)
            dt = time.perf_counter() - t0
            if dt < best:
                best, events = dt, 2 * plant.counts.impacts
        print(f"{name:32s} {a.particles:6d} {a.hours:5.1f} {best:7.2f} {events / best:10.3g} {a.hours * 3600 / best:11.3g}")


if __name__ == "__main__":
    main()
