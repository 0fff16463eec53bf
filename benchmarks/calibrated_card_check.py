"""A calibrated card predicts its own plant: the lab card with gamma x1.5, delta x0.6 (what `bmctl calibrate` writes).

    python benchmarks/calibrated_card_check.py [--seeds 3] [--particles 20000]

Writes the calibrated card to a temporary folder, identifies it (``bmctl identify``, as `bmctl calibrate`
does for the card it writes), and runs the card's recipe (300 rpm, 12 h) on a plant ensemble of that
card. Compares the plant's ensemble mean with the moment model on three sets of coefficients: the
card's own (identified), the lab card's (another card's), and the built-in defaults: s_mean at 12 h
(µm) and the NRMSE of each moment over the recipe (``identify.nrmse``), beside the own coefficients'
held-out NRMSE (mean over its held-out schedules). Writes ``results/calibrated_card.json``.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

LAB = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
GAMMA, DELTA = 1.5, 0.6


def main() -> None:
    from bmctl.calibrate.outputs import calibrated_card, write_card
    from bmctl.config import load_card
    from bmctl.moments import coeffs as cf
    from bmctl.moments import identify as ident
    from bmctl.moments.model import make_moment_model

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--particles", type=int, default=20000)
    ap.add_argument("--no-results", action="store_true")
    a = ap.parse_args()
    lab = load_card(LAB)
    st = lab.stochastic
    card = calibrated_card(lab, ("gamma", "delta"), (st.gamma_per_um2 * GAMMA, st.delta_per_um2 * DELTA),
                           f"gamma x{GAMMA}, delta x{DELTA} (benchmarks/calibrated_card_check.py)")
    tmp = Path(tempfile.mkdtemp(prefix="calibrated-card-"))
    path = write_card(tmp / "alni-1to1-300rpm-lab-calibrated.toml", card)
    subprocess.run([sys.executable, "-m", "bmctl", "identify", str(path), "--quiet"], cwd=ROOT, check=True,
                   stdout=subprocess.DEVNULL, env={**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"})
    own = cf.read_file(cf.coeffs_path(path))
    spec = ident.Spec("recipe", ident._grid([(12.0, card.process.rpm, 1.0)]))
    (run,) = ident.run_experiments(card, [spec], list(range(101, 101 + a.seeds)), a.particles)
    names = ident.MOMENTS[:4]
    values = {"plant_s_mean_12h_um": round(float(run.Y[-1, 0]), 2),
              "own_heldout_mean_pct": {k: round(100 * float(own.heldout_mean[k]), 2) for k in names},
              "own_heldout_max_pct": {k: round(100 * float(own.heldout_max[k]), 2) for k in names}}
    for label, coeffs in (("own", cf.coeffs_path(path)), ("lab", cf.coeffs_path(LAB)), ("defaults", {})):
        model = make_moment_model(card, coeffs)
        X = ident.predict(model, run)
        values[label] = {"s_mean_12h_um": round(float(X[-1, 0]), 2),
                         "s_mean_12h_error_pct": round(100 * float(X[-1, 0] / run.Y[-1, 0] - 1), 2),
                         "nrmse_pct": {k: round(100 * float(v), 2) for k, v in zip(names, ident.nrmse(X, run.Y))}}
        print(f"{label:9s} s_mean at 12 h {X[-1, 0]:.1f} µm (plant {run.Y[-1, 0]:.1f} µm); NRMSE over the recipe "
              + ", ".join(f"{k} {v:.2f} %" for k, v in values[label]["nrmse_pct"].items()))
    print("own coefficients' held-out NRMSE (mean over its schedules): "
          + ", ".join(f"{k} {v:.2f} %" for k, v in values["own_heldout_mean_pct"].items()))
    values["own_within_heldout_mean"] = [k for k in names if values["own"]["nrmse_pct"][k]
                                         <= values["own_heldout_mean_pct"][k]]
    values["own_within_heldout_max"] = [k for k in names if values["own"]["nrmse_pct"][k]
                                        <= values["own_heldout_max_pct"][k]]
    if not a.no_results:
        from bmctl.results import write_results

        print("wrote", write_results("calibrated_card", values, command="python benchmarks/calibrated_card_check.py",
                                     settings={"card": "lab", "gamma_factor": GAMMA, "delta_factor": DELTA,
                                               "rpm": card.process.rpm, "hours": 12.0, "seeds": a.seeds,
                                               "particles": a.particles}))
    assert np.isfinite(values["plant_s_mean_12h_um"])


if __name__ == "__main__":
    main()
