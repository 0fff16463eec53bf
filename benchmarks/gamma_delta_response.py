"""How strongly the plant's bonding and fracture rates respond to its gamma and delta.

For states reached on the card and on the two +-30 % plants (gamma x1.3, delta x0.7 and the
reverse) at two speeds, the state is snapshotted and continued for 15 min with gamma or delta
raised and lowered by 30 % (common random numbers: the same generator state for the four
continuations). The log ratio of the event counts over ln(1.3 / 0.7) is the rate's elasticity
to that factor at that state: 1 for a probability proportional to the factor, 0 where it is
saturated (eqns 15 and 20 are clipped at 1). docs/moments.md (Sec. 2, "The parameters p") uses
the table to explain why p acts inside the saturation of the moment model.

    python benchmarks/gamma_delta_response.py [--card models/<card>.toml] [--particles 5000]

Writes results/gamma_delta_response.json (the mean, min and max of each elasticity over the
states, and the same at each speed) unless ``--no-results``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from bmctl.config import load_card, with_factors
from bmctl.plant.plant import Plant

CONTINUATIONS = {"g+": (1.3, 1.0), "g-": (0.7, 1.0), "d+": (1.0, 1.3), "d-": (1.0, 0.7)}


def elasticities(card, rpm: float, start: tuple[float, float], times, particles: int, seed: int = 7,
                 dt_h: float = 0.25) -> list[dict]:
    """Rate elasticities (bond to gamma, bond to delta, fracture to gamma, fracture to delta) at
    the states of a run of the ``start`` plant at ``rpm``, one dict per time."""
    plant = Plant(with_factors(card, *start), np.random.default_rng(seed), particles)
    rows, t = [], 0.0
    for t_h in times:
        plant.advance(rpm, t_h - t)
        t = t_h
        snap = plant.snapshot()
        counts = {}
        for name, f in CONTINUATIONS.items():
            q = Plant(with_factors(card, *f), np.random.default_rng(0), particles)
            q.restore(snap)
            q.rng = np.random.default_rng([seed, int(t_h * 10), int(rpm)])  # common random numbers
            c0 = q.counts.copy()
            q.advance(rpm, dt_h)
            counts[name] = (q.counts.bonds - c0.bonds, q.counts.fractures - c0.fractures)
        span = np.log(1.3 / 0.7)
        e = {
            "bond/gamma": np.log(counts["g+"][0] / counts["g-"][0]) / span,
            "bond/delta": np.log(counts["d+"][0] / counts["d-"][0]) / span,
            "frac/gamma": np.log(counts["g+"][1] / counts["g-"][1]) / span,
            "frac/delta": np.log(counts["d+"][1] / counts["d-"][1]) / span,
        }
        rows.append({"rpm": rpm, "start": start, "t_h": t_h, "s_mean_um": plant.moments()["s_mean_um"],
                     "events": sum(counts["g+"]), **e})
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--card", default="models/alni-1to1-300rpm-lab.toml")
    ap.add_argument("--particles", type=int, default=5000)
    ap.add_argument("--no-results", action="store_true", help="do not write results/gamma_delta_response.json")
    args = ap.parse_args(argv)
    card = load_card(args.card)
    t0 = time.time()
    keys = ("bond/gamma", "bond/delta", "frac/gamma", "frac/delta")
    print("| rpm | plant (gamma, delta) | t (h) | s_mean (um) | " + " | ".join(keys) + " |")
    print("|---|---|---|---|" + "---|" * len(keys))
    rows = []
    for share in (0.5, 5 / 6):
        rpm = round(share * card.mill.rpm_max / 10) * 10
        for start in ((1.0, 1.0), (1.3, 0.7), (0.7, 1.3)):
            for r in elasticities(card, rpm, start, (1, 3, 6, 12), args.particles):
                rows.append(r)
                print(f"| {rpm:g} | {start} | {r['t_h']:g} | {r['s_mean_um']:.1f} | "
                      + " | ".join(f"{r[k]:+.2f}" for k in keys) + " |", flush=True)
    E = np.array([[r[k] for k in keys] for r in rows])
    print("| all | | | mean (min, max) | " + " | ".join(f"{m:+.2f} ({lo:+.2f}, {hi:+.2f})" for m, lo, hi in
                                                    zip(E.mean(0), E.min(0), E.max(0))) + " |")
    print(f"\n{len(rows)} states, {time.time() - t0:.0f} s")
    if not args.no_results:
        from bmctl.results import write_results

        def summary(sel):
            M = np.array([[r[k] for k in keys] for r in sel])
            return {k.replace("/", "_"): {"mean": float(M[:, i].mean()), "min": float(M[:, i].min()),
                                          "max": float(M[:, i].max())} for i, k in enumerate(keys)}

        speeds = sorted({r["rpm"] for r in rows})
        values = {"states": len(rows), "all": summary(rows),
                  "by_rpm": {f"{rpm:g}": {**summary([r for r in rows if r["rpm"] == rpm]),
                                          "s_mean_um_min": min(r["s_mean_um"] for r in rows if r["rpm"] == rpm),
                                          "s_mean_um_max": max(r["s_mean_um"] for r in rows if r["rpm"] == rpm)}
                             for rpm in speeds},
                  "rows": [{"rpm": r["rpm"], "start": list(r["start"]), "t_h": r["t_h"], "s_mean_um": r["s_mean_um"],
                            **{k.replace("/", "_"): r[k] for k in keys}} for r in rows]}
        cmd = "python benchmarks/gamma_delta_response.py"
        if args.card != "models/alni-1to1-300rpm-lab.toml" or args.particles != 5000:
            cmd += f" --card {args.card} --particles {args.particles}"
        path = write_results("gamma_delta_response", values, settings={
            "card": Path(args.card).name, "particles": args.particles, "speeds_rpm": speeds, "times_h": [1, 3, 6, 12],
            "starts": [[1.0, 1.0], [1.3, 0.7], [0.7, 1.3]], "continuation_h": 0.25, "factor_steps": [0.7, 1.3]},
            command=cmd)
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
