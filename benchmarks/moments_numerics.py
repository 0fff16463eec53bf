"""Numerics of the moment model on the shipped cards: the RKC substep's error and the linear analysis.

1. Discretisation: each card's model (its own coefficients) on 3 held-out schedules of
   ``bmctl identify`` (stream [0, 2]) and 6 constant speeds (rpm_max/6 ... rpm_max), 12 h at
   dt 0.5 h, stepped with RKC substeps of 1/16 h (the default) and 1/8 h against 1/64 h. NRMSE as
   in identify (RMSE over the half-hour records / range of the reference trajectory, floored at
   10 % of its mean), mean and worst over the 9 runs, in percent.
2. Linear analysis as ``bmctl linearize models/<card>.toml`` prints it (the card's rpm, after
   6 h, gramian horizon 2 h): eigenvalues (1/h), ranks, gramian condition numbers.

    python benchmarks/moments_numerics.py        # well under a minute; writes results/moments_numerics.json
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bmctl.config import load_card  # noqa: E402
from bmctl.moments import identify as ident  # noqa: E402
from bmctl.moments.linear import analyse, operating_point  # noqa: E402
from bmctl.moments.model import make_moment_model  # noqa: E402

COMMAND = "python benchmarks/moments_numerics.py"
DT_H = 0.5
SUBSTEPS = {"h16": 8, "h8": 4, "h64": 32}  # substeps per 0.5 h: 1/16 h, 1/8 h, 1/64 h (reference)
NAMES = ("s_mean_um", "s_std_um", "r_mean", "r_std")


def trajectory(F, x0, U, p) -> np.ndarray:
    X = [np.asarray(x0, dtype=float)]
    for u in U:
        X.append(np.asarray(F(X[-1], u, p)).ravel())
    return np.array(X)


def discretisation(model, card) -> dict:
    schedules = [np.array(s.inputs, dtype=float) for s in ident.validation_design(card, 0, 3, 2)]
    rpm_max = card.mill.rpm_max
    schedules += [np.tile([k / 6 * rpm_max, 1.0], (int(ident.HOURS / DT_H), 1)) for k in range(1, 7)]
    steps = {k: model.casadi_step(DT_H, substeps=n) for k, n in SUBSTEPS.items()}
    x0, p = model.x0(), model.p0()
    out = {}
    for k in ("h16", "h8"):
        rows = []
        for U in schedules:
            ref = trajectory(steps["h64"], x0, U, p)
            rows.append(ident.nrmse(trajectory(steps[k], x0, U, p), ref)[:4] * 100)
        rows = np.array(rows)
        out[k] = {"mean_pct": dict(zip(NAMES, rows.mean(0))), "max_pct": dict(zip(NAMES, rows.max(0)))}
    out["runs"] = len(schedules)
    return out


def linear(model, card) -> dict:
    x, u = operating_point(model, card.process.rpm, 6.0)
    a = analyse(model, x, u, horizon_h=2.0)
    ev = np.sort(np.real(a["eig"]))
    return {"rpm": card.process.rpm, "eig_per_h": ev, "eig_max_imag": float(np.max(np.abs(np.imag(a["eig"])))),
            "ctrb_rank": a["ctrb_rank"], "ctrb_rank_rpm": a["ctrb_rank_rpm"],
            "ctrb_rank_milling": a["ctrb_rank_milling"], "obsv_rank": a["obsv_rank"],
            "obsv_rank_no_r": a["obsv_rank_no_r"], "gram_c_cond": a["gram_c_cond"], "gram_o_cond": a["gram_o_cond"],
            "temperature_rate_per_h": 3600.0 / card.thermal.cooling_time_s}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--no-results", action="store_true")
    args = ap.parse_args(argv)
    cards = {}
    for path in sorted((ROOT / "models").glob("*.moments.toml")):
        card_path = path.with_name(path.name.removesuffix(".moments.toml") + ".toml")
        card = load_card(card_path)
        model = make_moment_model(card_path)
        c = {"discretisation": discretisation(model, card), "linear": linear(model, card)}
        cards[card.card.name] = c
        d, lin = c["discretisation"], c["linear"]
        print(f"{card.card.name}: 1/16 h vs 1/64 h NRMSE mean " + ", ".join(f"{v:.2f}" for v in d["h16"]["mean_pct"].values())
              + " %, worst " + ", ".join(f"{v:.2f}" for v in d["h16"]["max_pct"].values())
              + " %; 1/8 h worst " + ", ".join(f"{v:.2f}" for v in d["h8"]["max_pct"].values()) + " %")
        print(f"  linear at {lin['rpm']:g} rpm, 6 h: eig " + ", ".join(f"{e:.3g}" for e in lin["eig_per_h"])
              + f"; ctrb {lin['ctrb_rank']} (rpm {lin['ctrb_rank_rpm']}, milling {lin['ctrb_rank_milling']}); "
              f"obsv {lin['obsv_rank']} (size {lin['obsv_rank_no_r']}); cond Wc {lin['gram_c_cond']:.3g}, "
              f"Wo {lin['gram_o_cond']:.3g}", flush=True)
    if not args.no_results:
        from bmctl.results import write_results

        path = write_results("moments_numerics", {"cards": cards}, settings={
            "dt_h": DT_H, "hours": ident.HOURS, "substeps_per_interval": SUBSTEPS, "heldout_schedules": 3,
            "heldout_stream": [0, 2], "constant_speeds": "rpm_max k/6, k = 1..6", "linear_at_h": 6.0,
            "gramian_horizon_h": 2.0}, command=COMMAND)
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
