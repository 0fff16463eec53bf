"""Closed-loop study of MPC variants against LQR baselines: final error and vial-ceiling margin over seeds.

Run (the full study, 20 seeds; each 12 h MPC trial takes minutes on a loaded 2-core machine):

    nice python benchmarks/control_study.py --seeds 20 --jobs 2 --out out/control_study

Cases: two scenarios -- ``mismatch`` (plant gamma x1.3, delta x0.7 off the card; s_mean 45 um)
and ``target-size`` (plant on the card; s_mean 45 um) -- times four controllers: ``mpc-default``
(nominal offset-free MPC), ``mpc-scenario`` (scenario MPC on the filter's spread),
``lqr-baseline`` (LQR, milling lowered by the temperature guard) and ``lqr-clip`` (LQR, rpm
clipped to keep the ceiling). Each (case, seed) runs ``bmctl.trial.run_trial`` into
OUT/<case>/seed<N>; a finished run (summary.json present) is reused. Prints and writes
(OUT/table.md) a markdown table: final relative error (mean +- standard error over seeds), peak
vial temperature, ceiling margin (ceiling - peak; min over seeds), energy, fallbacks, seeds run.
"""

from __future__ import annotations

import argparse
import json
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = {
    "mismatch": {"gamma_factor": 1.3, "delta_factor": 0.7},
    "target-size": {},
}
CONTROLLERS = ("mpc-default", "mpc-scenario", "lqr-baseline", "lqr-clip")
TARGET = {"s_mean_um": 45.0}


def scenario_file(folder: Path, scen: str, ctrl: str) -> Path:
    """Write the trial scenario of one case (absolute paths to the card and the controller)."""
    folder.mkdir(parents=True, exist_ok=True)
    plant = SCENARIOS[scen]
    lines = [f'model = "{ROOT / "models/alni-1to1-300rpm-lab.toml"}"', "hours = 12",
             "target = { " + ", ".join(f"{k} = {v}" for k, v in TARGET.items()) + " }", "",
             "[scenario]", f'name = "{scen}-{ctrl}"', f'description = "control study: {scen} with {ctrl}"', ""]
    if plant:
        lines += ["[plant]"] + [f"{k} = {v}" for k, v in plant.items()] + [""]
    lines += ["[controller]", f'config = "{ROOT / "controllers" / (ctrl + ".toml")}"', ""]
    path = folder / f"{scen}-{ctrl}.toml"
    path.write_text("\n".join(lines))
    return path


def run_one(job) -> dict:
    from bmctl.trial import run_trial

    scen_path, out, seed = job
    summ = Path(out) / "summary.json"
    if summ.exists():
        return json.loads(summ.read_text())
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    lock = Path(f"{out}.running")  # another study process runs this case (two may share --out)
    try:
        os.close(os.open(lock, os.O_CREAT | os.O_EXCL))
    except FileExistsError:
        return None
    try:
        resume = (Path(out) / "checkpoint.npz").exists()
        return run_trial(scen_path, out, seed=seed, resume=resume)
    finally:
        lock.unlink()


def table(results: dict) -> str:
    rows = ["| scenario | controller | seeds | final error % (mean ± se) | peak T °C (mean) | ceiling margin °C "
            "(mean; min) | energy kJ | fallbacks |", "|---|---|---|---|---|---|---|---|"]
    for (scen, ctrl), summ in results.items():
        if not summ:
            continue
        err = np.array([100 * max(s["final_error"].values()) for s in summ])
        peak = np.array([s["max_temperature_c"] for s in summ])
        margin = np.array([s["temperature_ceiling_c"] - s["max_temperature_c"] for s in summ])
        en = np.array([s["energy_kj"] for s in summ])
        fb = sum(s["fallbacks"] for s in summ)
        se = err.std(ddof=1) / np.sqrt(len(err)) if len(err) > 1 else float("nan")
        rows.append(f"| {scen} | {ctrl} | {len(summ)} | {err.mean():.2f} ± {se:.2f} | {peak.mean():.1f} | "
                    f"{margin.mean():.1f}; {margin.min():.1f} | {en.mean():.0f} | {fb} |")
    return "\n".join(rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", default="out/control_study")
    ap.add_argument("--controllers", nargs="+", default=list(CONTROLLERS))
    ap.add_argument("--table-only", action="store_true", help="tabulate the finished runs under --out")
    ap.add_argument("--reverse", action="store_true",
                    help="last seed first: a second process on the same --out meets the first in the middle")
    a = ap.parse_args()
    out = Path(a.out)
    cases = [(s, c) for s in SCENARIOS for c in a.controllers]
    jobs = {}
    for seed in (reversed if a.reverse else iter)(range(a.seeds)):  # seed-major: every case gets its first seeds before any gets more
        for scen, ctrl in cases:
            jobs[(scen, ctrl, seed)] = (str(scenario_file(out / "scenarios", scen, ctrl)),
                                        str(out / f"{scen}-{ctrl}" / f"seed{seed}"), seed)
    results: dict = {c: [] for c in cases}
    if not a.table_only:
        with ProcessPoolExecutor(max_workers=a.jobs) as ex:
            futs = {k: ex.submit(run_one, j) for k, j in jobs.items()}
            for (scen, ctrl, seed), f in futs.items():
                s = f.result()
                if s is None:
                    print(f"{scen} {ctrl} seed {seed}: running in another process", flush=True)
                    continue
                print(f"{scen} {ctrl} seed {seed}: error {100 * max(s['final_error'].values()):.2f} %, "
                      f"peak {s['max_temperature_c']:.1f} C", flush=True)
    for (scen, ctrl, seed), (_, o, _) in jobs.items():
        p = Path(o) / "summary.json"
        if p.exists():
            results[(scen, ctrl)].append(json.loads(p.read_text()))
    text = table(results)
    (out / "table.md").write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
