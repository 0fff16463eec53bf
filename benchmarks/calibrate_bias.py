"""Bias and interval coverage of ``bmctl calibrate`` over synthetic truths it was not tuned on.

Each case draws its own truth: γ and δ multipliers log-uniform in [×0.5, ×2] on the lab card
(``models/alni-1to1-300rpm-lab.toml``), from ``SeedSequence(seed)`` with seeds 1000, 1001, ...
(the method's settings were chosen on seeds 1-20 of ``calibrate_accuracy.py``, one truth).
Even cases have one history (12 h at 300 rpm), odd cases two (12 h at 250 rpm and 12 h at
400 rpm, as a user with two runs at different speeds has). Each history is sampled with 300
particles at 2, 4, 6 and 8 h from a 20,000-particle true plant; γ and δ are fitted from the
card. Reported: per case the estimate, 90 % interval and stop reason; over all cases the median
relative error (bias) of γ and δ, the share of 90 % intervals that cover the truth, rms error and
median interval width (hi / lo).

    python benchmarks/calibrate_bias.py --workers 2            # 24 cases, writes results/calibrate_bias.json
    python benchmarks/calibrate_bias.py --cases 4 --no-results # a quick look
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bmctl.calibrate.fit import FitSettings  # noqa: E402
from bmctl.calibrate.run import run_calibration  # noqa: E402
from bmctl.calibrate.synthetic import synthetic_history  # noqa: E402
from bmctl.config import load_card, with_factors  # noqa: E402
from bmctl.parallel import client_for, close_client  # noqa: E402

CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
TIMES = (2.0, 4.0, 6.0, 8.0)
N_SAMPLE = 300
TRUE_PARTICLES = 20000
HOURS = 12.0
ONE_RPM = (300.0,)
TWO_RPM = (250.0, 400.0)
LO, HI = 0.5, 2.0  # truth multipliers, log-uniform
COMMAND = "python benchmarks/calibrate_bias.py --workers 2"


def truth(seed: int) -> tuple[float, float]:
    """(γ, δ) multipliers of case ``seed``: log-uniform in [LO, HI], from the case's own stream."""
    rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(3)[0])
    g, d = np.exp(rng.uniform(math.log(LO), math.log(HI), 2))
    return float(g), float(d)


def histories(seed: int, gamma_x: float, delta_x: float, rpms) -> list:
    card = with_factors(load_card(CARD), gamma_x, delta_x)
    data_ss = np.random.SeedSequence(seed).spawn(3)[1].spawn(len(rpms))
    return [synthetic_history(card, [(HOURS, rpm, 1.0)], TIMES, N_SAMPLE, TRUE_PARTICLES, np.random.default_rng(ss),
                              name=f"h{rpm:.0f}") for rpm, ss in zip(rpms, data_ss)]


def case(seed: int, client, settings: FitSettings) -> dict:
    rpms = TWO_RPM if seed % 2 else ONE_RPM
    g, d = truth(seed)
    hs = histories(seed, g, d, rpms)
    t0 = time.perf_counter()
    res = run_calibration(load_card(CARD), CARD, hs, ["gamma", "delta"], None, seed=seed, settings=settings,
                          client=client)
    cal = res.calibration
    row = {"seed": seed, "rpms": list(rpms), "wall_s": time.perf_counter() - t0, "plant_runs": cal.plant_runs,
           "chi2": cal.chi2, "n_summaries": cal.n_summaries, "converged": cal.converged,
           "stop_reason": cal.stop_reason, "start": cal.start_choice.get("start", "card")}
    for i, (n, t) in enumerate((("gamma", g), ("delta", d))):
        cv = cal.card_values[i]
        est, lo, hi = cal.values[i] / cv, cal.lo90[i] / cv, cal.hi90[i] / cv
        row[n] = {"truth": t, "estimate": est, "lo90": lo, "hi90": hi, "rel_err": est / t - 1.0,
                  "covered": bool(lo <= t <= hi), "width": hi / lo}
    return row


def summarise(rows: list[dict]) -> dict:
    out = {}
    for n in ("gamma", "delta"):
        err = np.array([r[n]["rel_err"] for r in rows])
        out[n] = {"median_bias_pct": 100 * float(np.median(err)),
                  "coverage": float(np.mean([r[n]["covered"] for r in rows])),
                  "covered": int(sum(r[n]["covered"] for r in rows)),
                  "above_truth": int(np.sum(err > 0)),
                  "rms_error_pct": 100 * float(np.sqrt(np.mean(np.log1p(err) ** 2))),
                  "median_width": float(np.median([r[n]["width"] for r in rows]))}
    out["cases"] = len(rows)
    out["converged"] = int(sum(r["converged"] for r in rows))
    out["plant_runs_median"] = float(np.median([r["plant_runs"] for r in rows]))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=24)
    ap.add_argument("--first", type=int, default=1000)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--no-results", action="store_true", help="print only; do not write results/calibrate_bias.json")
    a = ap.parse_args(argv)
    settings = FitSettings()
    client = client_for(None, a.workers)
    rows = []
    try:
        for k in range(a.cases):
            r = case(a.first + k, client, settings)
            rows.append(r)
            g, d = r["gamma"], r["delta"]
            print(f"seed {r['seed']} rpm {'+'.join(f'{x:.0f}' for x in r['rpms'])}: "
                  f"γ ×{g['estimate']:.3f} [{g['lo90']:.3f}, {g['hi90']:.3f}] truth ×{g['truth']:.3f}; "
                  f"δ ×{d['estimate']:.3f} [{d['lo90']:.3f}, {d['hi90']:.3f}] truth ×{d['truth']:.3f}; "
                  f"{r['plant_runs']} runs, {r['wall_s']:.0f} s{'' if r['converged'] else ', not converged'}",
                  flush=True)
    finally:
        close_client(client)
    summary = summarise(rows)
    for n in ("gamma", "delta"):
        s = summary[n]
        print(f"{n}: median bias {s['median_bias_pct']:+.1f} %, 90 % coverage {s['covered']}/{len(rows)} "
              f"({s['coverage']:.2f}), above truth {s['above_truth']}/{len(rows)}, rms error of ln "
              f"{s['rms_error_pct']:.0f} %, median width ×{s['median_width']:.2f}")
    if not a.no_results:
        from bmctl.results import write_results

        one = summarise([r for r in rows if len(r["rpms"]) == 1])
        two = summarise([r for r in rows if len(r["rpms"]) == 2])
        write_results("calibrate_bias", {"summary": summary, "one_rpm": one, "two_rpm": two, "cases": rows},
                      settings={"cases": a.cases, "first_seed": a.first, "workers": a.workers, "card": CARD.name,
                                "truth_range": [LO, HI], "times_h": list(TIMES), "sample_particles": N_SAMPLE,
                                "true_particles": TRUE_PARTICLES, "hours": HOURS, "one_rpm": list(ONE_RPM),
                                "two_rpm": list(TWO_RPM), "fit": settings.model_dump()},
                      command=COMMAND)
    return 0


if __name__ == "__main__":
    sys.exit(main())
