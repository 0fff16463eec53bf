"""Speed of the measurement path: segmentation per image, and the micrograph sampler.

Run from the repository root::

    python benchmarks/bench_measure.py [--repeat 3]

Prints one Markdown table (median wall time of ``--repeat`` runs, single process).
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

from bmctl.measure import load_image, measure_image, micrograph_sample, render_micrograph
from bmctl.measure.micrograph import measure_micrograph

DATA = Path(__file__).resolve().parents[1] / "tests" / "data"


def _time(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    rows = []
    syn = render_micrograph(np.random.default_rng(0), n=200, shape=(1024, 1024), s_px=(15, 60))
    rows.append(("segment + measure, synthetic 1024x1024, 200 particles", _time(lambda: measure_image(syn.image, 1.0), args.repeat)))
    png = DATA / "ampis_powder_b.png"
    if png.exists():
        img = load_image(png)
        rows.append(("segment + measure, AMPIS powder 1536x1024 (~240 particles)", _time(lambda: measure_image(img, 1.0), args.repeat)))
    tif = DATA / "sio2_sem_12000x.tif"
    if tif.exists():
        img2 = load_image(tif)
        rows.append(("segment + measure, SiO2 712x423 cropped (~500 particles)", _time(lambda: measure_image(img2, 0.0368, crop="0:423,:"), args.repeat)))
        rows.append(("measure_micrograph, SiO2 712x484 (scale from metadata, data bar found, checks)",
                     _time(lambda: measure_micrograph(tif), args.repeat)))
    rng = np.random.default_rng(1)
    s = rng.lognormal(np.log(40.0), 0.4, 10000)
    r = np.clip(rng.gamma(2.0, 0.03, 10000), 0, 0.6)
    rows.append(("micrograph_sample fast path, n = 1000", _time(lambda: micrograph_sample(s, r, 1000, rng, um_per_px=1.0), args.repeat)))
    rows.append(("micrograph_sample render path, n = 200", _time(lambda: micrograph_sample(s, r, 200, rng, um_per_px=2.0, render=True), args.repeat)))
    print("| case | median s |")
    print("|---|---|")
    for name, t in rows:
        print(f"| {name} | {t:.3g} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
