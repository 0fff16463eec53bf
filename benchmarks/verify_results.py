"""Numbers behind docs/verification.md: ``bmctl verify`` (full settings) as a results file.

Runs every check of :func:`bmctl.validation.report.run_all` on the three shipped cards and writes
``results/verify.json``: per analytic case and M the rms errors and the i.i.d. expectation, the bias
test (max |t|, Bonferroni p), the M^-1/2 slopes; the loop energetics, the plant-vs-reference
comparison and the bookkeeping; and the pass count.

    python benchmarks/verify_results.py              # full settings, seed 0 (~10 min on one core)
    python benchmarks/verify_results.py --quick      # bmctl verify --quick's settings
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bmctl.config import load_card  # noqa: E402
from bmctl.validation import report as R  # noqa: E402

CARDS = {"lab": "alni-1to1-300rpm-lab", "fan": "alni-1to1-400rpm-fan", "1:3": "alni-1to3-300rpm-hadjiafxenti"}


def values(rep: R.Report) -> dict:
    table = R.rows(rep)
    tests = [r for r in table if r[-1] in ("pass", "FAIL")]
    out = {"checks": len(tests), "passed": sum(r[-1] == "pass" for r in tests), "analytic": {}, "loop": {},
           "reference": {}, "bookkeeping": {}}
    for res in rep.analytic:
        worst = max(res.bias_z, key=lambda k: abs(res.bias_z[k]))
        out["analytic"][res.case.name] = {
            "rms": {str(M): res.rms[M] for M in res.sizes}, "expected": {str(M): res.expected[M] for M in res.sizes},
            "bias_max_t": res.max_z, "bias_worst": worst, "bias_p": res.bias_p, "slopes": res.slopes}
    short = {v: k for k, v in CARDS.items()}
    for name, e in rep.energetics.items():
        out["loop"][short.get(name, name)] = {
            "rate_rel": e.rate_wald / e.rate_plant - 1, "rate_se": e.rate_wald_se / e.rate_plant,
            "plastic_diff": e.plastic_loop - e.plastic_plant, "plastic_se": e.plastic_loop_se,
            "u_in_rel": e.u_in_loop / e.u_in_plant - 1, "u_in_se": e.u_in_loop_se / e.u_in_plant,
            "overshoot": e.overshoot, "impacts_per_collision": e.steps_per_collision}
    for cmp in rep.reference:
        d = {}
        for k in R.REFERENCE_MOMENTS:
            a, b = cmp.plant[k], cmp.reference[k]
            d[k] = {"diff": float(a.mean() - b.mean()),
                    "se": float(math.sqrt(a.var(ddof=1) / a.size + b.var(ddof=1) / b.size))}
        d["moments_p"] = cmp.moments_p
        d["ks"] = {k: {"distance": float(dist), "p": float(p)} for k, (dist, p) in cmp.ks.items()}
        out["reference"][short.get(cmp.card, cmp.card)] = d
    for b in rep.bookkeeping:
        out["bookkeeping"][short.get(b.card, b.card)] = {
            "area_err": b.area_err, "total_area_err": b.total_area_err, "n_z": b.n_z, "impacts_z": b.impacts_z,
            "impacts": int(b.counts[0]), "s_min_um": b.s_min * 1e6, "r_min": b.r_min, "r_max": b.r_max, "hours": b.hours}
    return out


def probe(seeds: int = 24, M: int = 8000) -> dict:
    """The agglomeration-constant case's CDF error at its deciles at tau = 3, over many seeds at one M: the
    bias the quick verification's check flags on some seed sets (docs/verification.md)."""
    import numpy as np

    from bmctl.validation import cases as C

    case = C.agglomeration_constant()
    e = np.array([C.run_case(case, M, s).cdf_err[1] for s in range(seeds)])
    mean, se = e.mean(axis=0), e.std(axis=0, ddof=1) / np.sqrt(seeds)
    return {"M": M, "seeds": seeds, "tau": case.times[1], "quantiles": C.QUANTILES.tolist(), "mean": mean.tolist(),
            "se": se.tolist(), "t": (mean / se).tolist(), "f09_mean": float(mean[-1]), "f09_se": float(se[-1]),
            "f09_t": float(mean[-1] / se[-1])}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-results", action="store_true")
    a = ap.parse_args(argv)
    settings = R.QUICK if a.quick else R.FULL
    cards = [load_card(ROOT / "models" / f"{n}.toml") for n in CARDS.values()]
    rep = R.run_all(settings, a.seed, cards, progress=lambda line: print(line, flush=True))
    print(R.format_table(R.rows(rep)))
    vals = values(rep)
    print(f"{vals['passed']} of {vals['checks']} checks passed")
    if not a.quick:
        vals["probe_agglomeration_constant"] = probe()
        pr = vals["probe_agglomeration_constant"]
        print(f"agglomeration-constant, tau = {pr['tau']:g}, M = {pr['M']}, {pr['seeds']} seeds: F - F_exact at the 0.9 "
              f"decile {pr['f09_mean']:+.4f} ± {pr['f09_se']:.4f} (t = {pr['f09_t']:+.1f})")
    if not a.no_results:
        from bmctl.results import write_results

        write_results("verify_quick" if a.quick else "verify", vals,
                      settings={"seed": a.seed, "settings": settings.__dict__, "cards": list(CARDS.values())},
                      command="python benchmarks/verify_results.py" + (" --quick" if a.quick else "")
                      + (f" --seed {a.seed}" if a.seed else ""))
    return 0 if vals["passed"] == vals["checks"] else 1


if __name__ == "__main__":
    sys.exit(main())
