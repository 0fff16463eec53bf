"""Closed-loop study of MPC variants against LQR baselines: final error and vial-ceiling margin over seeds.

Run (writes results/control_study.json; ``--table`` prints the docs tables from it):

    nice python benchmarks/control_study.py --seeds 20 [--jobs 1] [--out out/control_study]

(20 seeds x 12 cases: about 45 min on a shared two-core machine with the compiled MPC solvers
cached; a finished trial is reused, so the study may be run in steps of a few seeds.)
    python benchmarks/control_study.py --table

Cases: two scenarios -- ``mismatch`` (plant gamma x1.3, delta x0.7 off the card; s_mean 45 um)
and ``target-size`` (plant on the card; s_mean 45 um) -- times six controllers: ``mpc-default``
(the plan on operable schedules), ``mpc-nlp`` (mpc-default.toml with ``[plan] method = "nlp"``:
the multiple-shooting NLP with the offset-free bias correction), ``mpc-nominal`` (the NLP without
the bias correction), ``mpc-scenario`` (the NLP with the bias correction, one plan also serving
the filter's gamma, delta quantile corners), ``lqr-baseline`` (LQR, milling lowered by
the temperature guard) and ``lqr-clip`` (LQR, rpm clipped to keep the ceiling). Each (case, seed)
runs ``bmctl.trial.run_trial`` (plant 5000 particles, particle filter 1000, a 300-particle
micrograph every hour) into OUT/<case>/seed<N>. A finished run is reused only if nothing it
depends on changed (fingerprint of the scenario, models/, controllers/ and the bmctl sources, as
in trial_study.py); two processes may share --out (``--reverse``). When every case has all its
seeds, the per-case numbers (|final error| of s_mean at 12 h: mean, standard error, worst;
signed mean; peak vial temperature, ceiling margin, trials whose plant crossed the ceiling, energy,
fallbacks) and the
paired differences of each MPC variant against each LQR (same seed: mean, standard error, seeds
where the MPC was closer, Wilcoxon signed-rank p from 6 seeds on) go to results/control_study.json.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from trial_study import fingerprint  # noqa: E402  (one rule for reusing a finished trial, in benchmarks/)

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = {
    "mismatch": {"gamma_factor": 1.3, "delta_factor": 0.7},
    "target-size": {},
}
CONTROLLERS = ("mpc-default", "mpc-nlp", "mpc-nominal", "mpc-scenario", "lqr-baseline", "lqr-clip")
#: controllers derived from a shipped file: name -> (file, replacements)
DERIVED = {"mpc-nlp": ("mpc-default", [('method = "search"', 'method = "nlp"'), ('name = "mpc-default"', 'name = "mpc-nlp"')])}
BASELINES = ("lqr-baseline", "lqr-clip")
TARGET = {"s_mean_um": 45.0}
NAME = "control_study"


def scenario_file(folder: Path, scen: str, ctrl: str) -> Path:
    """Write the trial scenario of one case (absolute paths to the card and the controller)."""
    folder.mkdir(parents=True, exist_ok=True)
    plant = SCENARIOS[scen]
    lines = [f'model = "{ROOT / "models/alni-1to1-300rpm-lab.toml"}"', "hours = 12",
             "target = { " + ", ".join(f"{k} = {v}" for k, v in TARGET.items()) + " }", "",
             "[scenario]", f'name = "{scen}-{ctrl}"', f'description = "control study: {scen} with {ctrl}"', ""]
    if plant:
        lines += ["[plant]"] + [f"{k} = {v}" for k, v in plant.items()] + [""]
    config = ROOT / "controllers" / (ctrl + ".toml")
    if ctrl in DERIVED:
        base, subs = DERIVED[ctrl]
        text = (ROOT / "controllers" / (base + ".toml")).read_text()
        for old, new in subs:
            if old not in text:
                raise SystemExit(f"control_study: {base}.toml has no {old!r} to derive {ctrl} from")
            text = text.replace(old, new)
        config = folder / f"{ctrl}.toml"
        if not config.exists() or config.read_text() != text:
            config.write_text(text)
    lines += ["[controller]", f'config = "{config}"', ""]
    path = folder / f"{scen}-{ctrl}.toml"
    text = "\n".join(lines)
    if not path.exists() or path.read_text() != text:
        path.write_text(text)
    return path


def finished(out: Path, fp: str) -> dict | None:
    """The summary of a finished run made with the current code, else None."""
    summ, stamp = out / "summary.json", out / "fingerprint.txt"
    if summ.exists() and stamp.exists() and stamp.read_text().strip() == fp:
        return json.loads(summ.read_text())
    return None


def run_one(job) -> dict | None:
    from bmctl.trial import run_trial

    scen_path, out, seed, fp = job
    out = Path(out)
    done = finished(out, fp)
    if done is not None:
        return done
    out.parent.mkdir(parents=True, exist_ok=True)
    lock = Path(f"{out}.running")  # another study process runs this case (two may share --out)
    try:
        os.close(os.open(lock, os.O_CREAT | os.O_EXCL))
    except FileExistsError:
        return None
    try:
        stamp = out / "fingerprint.txt"
        if out.exists() and (not stamp.exists() or stamp.read_text().strip() != fp):
            shutil.rmtree(out)  # made with other code, models or configs: start afresh
        out.mkdir(parents=True, exist_ok=True)
        stamp.write_text(fp + "\n")
        return run_trial(scen_path, out, seed=seed, resume=(out / "checkpoint.npz").exists())
    finally:
        lock.unlink()


def _se(x: np.ndarray) -> float:
    return float(x.std(ddof=1) / np.sqrt(len(x))) if len(x) > 1 else float("nan")


def case_numbers(summ: list[dict]) -> dict:
    """One case over its seeds (errors in %, temperatures in degC)."""
    signed = np.array([100 * (s["final_true"]["s_mean_um"] / TARGET["s_mean_um"] - 1) for s in summ])
    err = np.abs(signed)
    peak = np.array([s["max_temperature_c"] for s in summ])
    margin = np.array([s["temperature_ceiling_c"] - s["max_temperature_c"] for s in summ])
    return {"seeds": len(summ), "error_mean_pct": float(err.mean()), "error_se_pct": _se(err),
            "error_worst_pct": float(err.max()), "signed_mean_pct": float(signed.mean()),
            "above_target": int((signed > 0).sum()), "error_pct": err.tolist(),
            "peak_mean_c": float(peak.mean()), "peak_max_c": float(peak.max()),
            "margin_mean_c": float(margin.mean()), "margin_min_c": float(margin.min()),
            "energy_mean_kj": float(np.mean([s["energy_kj"] for s in summ])),
            "fallbacks": int(sum(s["fallbacks"] for s in summ)),
            "violations": int(sum(s["temperature_violations"] for s in summ)),
            "trials_over_ceiling": int(sum(s["temperature_violations"] > 0 for s in summ)),
            "solver_failures": int(sum(s["solver_failures"] for s in summ)),
            "gamma_est_min": float(min(s["final_estimate"]["gamma_mult"] for s in summ)),
            "gamma_est_max": float(max(s["final_estimate"]["gamma_mult"] for s in summ)),
            "median_solve_ms": float(np.median([s["median_solve_ms"] for s in summ]))}


def paired(a: dict, b: dict) -> dict:
    """|error| of controller a minus that of b, seed by seed (points of %)."""
    d = np.array(a["error_pct"]) - np.array(b["error_pct"])
    out = {"mean_pct": float(d.mean()), "se_pct": _se(d), "lower": int((d < 0).sum()), "n": len(d),
           "wilcoxon_p": None}
    if len(d) >= 6 and np.any(d != 0):
        from scipy.stats import wilcoxon

        out["wilcoxon_p"] = float(wilcoxon(d).pvalue)
    return out


def table(rec: dict) -> str:
    """The two Markdown tables of docs/control.md, every number in a results marker."""
    from bmctl.results import marked

    def m(key, value, fmt):
        return marked(NAME, key, value, fmt)

    rows = ["| scenario | controller | seeds | final error % (mean ± se) | worst % | signed mean % | peak T °C "
            "(mean) | ceiling margin °C (mean; min) | trials over the ceiling | energy kJ | fallbacks |",
            "|---|---|---|---|---|---|---|---|---|---|---|"]
    for scen, ctrls in rec["cases"].items():
        for ctrl, c in ctrls.items():
            k = f"cases.{scen}.{ctrl}"
            rows.append(f"| {scen} | {ctrl} | {m(k + '.seeds', c['seeds'], '{:d}')} | {m(k + '.error_mean_pct', c['error_mean_pct'], '{:.2f}')} ± "
                        f"{m(k + '.error_se_pct', c['error_se_pct'], '{:.2f}')} | "
                        f"{m(k + '.error_worst_pct', c['error_worst_pct'], '{:.2f}')} | "
                        f"{m(k + '.signed_mean_pct', c['signed_mean_pct'], '{:+.2f}')} | "
                        f"{m(k + '.peak_mean_c', c['peak_mean_c'], '{:.1f}')} | "
                        f"{m(k + '.margin_mean_c', c['margin_mean_c'], '{:.1f}')}; "
                        f"{m(k + '.margin_min_c', c['margin_min_c'], '{:.1f}')} | "
                        f"{m(k + '.trials_over_ceiling', c['trials_over_ceiling'], '{:d}')} | "
                        f"{m(k + '.energy_mean_kj', c['energy_mean_kj'], '{:.0f}')} | {m(k + '.fallbacks', c['fallbacks'], '{:d}')} |")
    base = list(next(iter(rec["paired"].values())).values())
    cols = list(base[0]) if base else []
    rows += ["", "| scenario | MPC | " + " | ".join(f"− {b}" for b in cols) + " |",
             "|---|---|" + "---|" * len(cols)]
    for scen, ctrls in rec["paired"].items():
        for ctrl, vs in ctrls.items():
            cells = []
            for b, d in vs.items():
                k = f"paired.{scen}.{ctrl}.{b}"
                cells.append(f"{m(k + '.mean_pct', d['mean_pct'], '{:+.2f}')} ± {m(k + '.se_pct', d['se_pct'], '{:.2f}')} "
                             f"(lower on {m(k + '.lower', d['lower'], '{:d}')} of {d['n']}"
                             + (f", p = {m(k + '.wilcoxon_p', d['wilcoxon_p'], '{:.2g}')})" if d.get("wilcoxon_p") is not None else ")"))
            rows.append(f"| {scen} | {ctrl} | " + " | ".join(cells) + " |")
    return "\n".join(rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--out", default=str(ROOT / "out" / "control_study"))
    ap.add_argument("--controllers", nargs="+", default=list(CONTROLLERS))
    ap.add_argument("--table", action="store_true", help="print the docs tables from results/control_study.json")
    ap.add_argument("--no-results", action="store_true", help="do not write results/control_study.json")
    ap.add_argument("--reverse", action="store_true",
                    help="last seed first: a second process on the same --out meets the first in the middle")
    a = ap.parse_args()
    if a.table:
        from bmctl.results import load_results

        print(table(load_results(NAME)))
        return
    out = Path(a.out)
    cases = [(s, c) for s in SCENARIOS for c in a.controllers]
    paths = {(s, c): str(scenario_file(out / "scenarios", s, c)) for s, c in cases}
    fps = {k: fingerprint(p) for k, p in paths.items()}
    jobs = {}
    for seed in (reversed if a.reverse else iter)(range(a.seeds)):  # seed-major: every case gets its first seeds first
        for scen, ctrl in cases:
            jobs[(scen, ctrl, seed)] = (paths[(scen, ctrl)], str(out / f"{scen}-{ctrl}" / f"seed{seed}"), seed,
                                        fps[(scen, ctrl)])
    with ProcessPoolExecutor(max_workers=a.jobs) as ex:
        futs = {k: ex.submit(run_one, j) for k, j in jobs.items()}
        for (scen, ctrl, seed), f in futs.items():
            s = f.result()
            if s is None:
                print(f"{scen} {ctrl} seed {seed}: running in another process", flush=True)
                continue
            print(f"{scen} {ctrl} seed {seed}: error {100 * s['final_error']['s_mean_um']:.2f} %, "
                  f"peak {s['max_temperature_c']:.1f} C", flush=True)
    results: dict = {}
    for (scen, ctrl, seed), (_, o, _, fp) in sorted(jobs.items(), key=lambda kv: kv[0][2]):
        s = finished(Path(o), fp)
        if s is not None:
            results.setdefault((scen, ctrl), []).append(s)
    if any(len(results.get(c, [])) < a.seeds for c in cases):
        print("not every case has all its seeds (another process still running?): no results file written")
        return
    rec = {"cases": {s: {c: case_numbers(results[(s, c)]) for c in a.controllers} for s in SCENARIOS}}
    mpcs = [c for c in a.controllers if c not in BASELINES]
    rec["paired"] = {s: {c: {b: paired(rec["cases"][s][c], rec["cases"][s][b]) for b in a.controllers if b in BASELINES}
                         for c in mpcs} for s in SCENARIOS}
    if not a.no_results:
        from bmctl.results import write_results

        cmd = f"python benchmarks/control_study.py --seeds {a.seeds}"
        path = write_results(NAME, rec, command=cmd, settings={
            "seeds": list(range(a.seeds)), "scenarios": SCENARIOS, "target": TARGET, "hours": 12,
            "card": "models/alni-1to1-300rpm-lab.toml", "controllers": a.controllers,
            "plant_particles": 5000, "filter": "pf, 1000 particles", "micrograph": "300 particles every 1 h",
            "ceiling_c": 80.0})
        print(f"wrote {path}")
    print(table(rec))


if __name__ == "__main__":
    main()
