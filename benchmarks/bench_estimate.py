"""Particle-filter speed: one update (N filter particles, n measured particles) and one predict.

Run:  python benchmarks/bench_estimate.py [--particles 2000] [--measured 300] [--repeat 30]

Prints the median and best wall time of ``ParticleFilter.update`` (guided proposal, sample
fit, rastered likelihood, weights, resampling when due) on a state cloud that has already
been through one hour of milling, and of ``ParticleFilter.predict`` over 1 h and 0.25 h
(dominated by the moment model's batched step). numpy runs single-threaded here.
Target: update <= 20 ms at N = 2000, n = 300.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from bmctl.estimate.filter import FilterSettings, ParticleFilter  # noqa: E402
from bmctl.moments.model import make_moment_model  # noqa: E402
from bmctl.plant.plant import MODELS_DIR, make_plant  # noqa: E402
from bmctl.plant.population import UM  # noqa: E402

CARD = MODELS_DIR / "alni-1to1-300rpm-lab.toml"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--particles", type=int, default=2000)
    ap.add_argument("--measured", type=int, default=300)
    ap.add_argument("--repeat", type=int, default=30)
    ap.add_argument("--size-law", default="weibull", choices=["weibull", "lognormal"])
    ap.add_argument("--no-results", action="store_true", help="do not write results/bench_estimate.json")
    a = ap.parse_args()
    load0, cpu0 = os.getloadavg(), time.process_time()
    from bmctl.estimate.likelihood import LawSettings
    from bmctl.measure.sampler import micrograph_sample

    model = make_moment_model(CARD)
    plant = make_plant(CARD, seed=0, particles=5000)
    plant.advance(300.0, 1.0)
    rng = np.random.default_rng(1)
    samples = [micrograph_sample(plant.s / UM, plant.r, a.measured, rng) for _ in range(a.repeat)]
    settings = FilterSettings(n_particles=a.particles, law=LawSettings(size_law=a.size_law))
    pf = ParticleFilter(model, np.random.default_rng(2), settings)
    t_pred = {}
    for dt in (1.0, 0.25):
        times = []
        for _ in range(3):
            X, P = pf.X.copy(), pf.logP.copy()
            t0 = time.perf_counter()
            pf.predict((300.0, 1.0), dt)
            times.append(time.perf_counter() - t0)
            pf.X, pf.logP, pf.t_h, pf.pending_h = X, P, pf.t_h - dt, pf.pending_h - dt
        t_pred[dt] = min(times)
    pf.predict((300.0, 1.0), 1.0)
    state = (pf.X.copy(), pf.logP.copy(), pf.logw.copy(), pf.q.copy(), pf.pending_h)
    times, ess = [], []
    for tab in samples:
        pf.X, pf.logP, pf.logw, pf.q, pf.pending_h = (v.copy() if hasattr(v, "copy") else v for v in state)
        t0 = time.perf_counter()
        est = pf.update(tab.s_um, tab.r)
        times.append(time.perf_counter() - t0)
        ess.append(est.ess)
    times = np.array(times) * 1e3
    print(f"filter particles N = {a.particles}, measured particles n = {a.measured}, size law {a.size_law}")
    print(f"update : median {np.median(times):6.1f} ms, best {times.min():6.1f} ms over {a.repeat} samples "
          f"(target <= 20 ms); ESS after update median {np.median(ess):.0f}")
    print(f"predict: 1 h {t_pred[1.0] * 1e3:6.1f} ms, 0.25 h {t_pred[0.25] * 1e3:6.1f} ms (best of 3; moment-model step)")
    if not a.no_results:
        from bmctl.results import write_results

        name = "bench_estimate" if a.size_law == "weibull" else f"bench_estimate_{a.size_law}"
        write_results(name, {"update_ms_median": float(np.median(times)), "update_ms_best": float(times.min()),
                             "ess_median": float(np.median(ess)), "predict_1h_ms": 1e3 * t_pred[1.0],
                             "predict_15min_ms": 1e3 * t_pred[0.25], "cpu_s": time.process_time() - cpu0,
                             "load_average_start": list(load0), "load_average_end": list(os.getloadavg())},
                      settings={"particles": a.particles, "measured": a.measured, "repeat": a.repeat,
                                "size_law": a.size_law, "threads": 1},
                      command="python benchmarks/bench_estimate.py" + ("" if a.size_law == "weibull" else
                                                                        f" --size-law {a.size_law}"))


if __name__ == "__main__":
    main()
