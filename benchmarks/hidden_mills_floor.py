"""What limits the final error on the hidden mills: the estimate the last advice saw, read from the step logs.

    python benchmarks/hidden_mills_floor.py     # writes results/hidden_mills_floor.json (seconds; reads results/)
    python benchmarks/hidden_mills_floor.py --figure docs/figures/hidden-mills-floor.png   # from that file

Reads the step logs of the default hidden-mill results files (``hidden_mills.py``, A-G on seeds
0-2 and the held-out H-L on seeds 0-1; each step holds the plant's and the estimate's mean size
at one advice) and relates each run's final error to the estimate's own error at the batch's last
advice: the plan steers its estimate to the target, so where the estimate is off at the last
advice the powder ends off by about as much, with the opposite sign. Written per run and summed up
over the runs: the RMS of the final errors, of the estimate's errors at the last advice and at
every hourly sample, their correlation (final error against minus the estimate's error), and the
RMS of what is left (final error plus the estimate's error); and the rests longer than the idle
bar (1 h) that began with the plant more than 2 % from the target, with the plant's and the
estimate's error against the target at their start. The scatter of one sample's mean
itself: ``hidden_mills.py --noise`` (``results/hidden_mills_noise.json``).

The same for the runs with 1000-particle samples (``hidden_mills.py --sample-particles 1000
--results-name hidden_mills_samples1000[...]``, key ``samples1000``) and for the runs whose operator
takes the extra samples the advice asks for (``--sample-on-request --results-name
hidden_mills_onrequest[...]``, key ``onrequest``) where those files exist, and for the default on the
mills of ``benchmarks/mills-unseen.toml`` (key ``unseen``) and ``benchmarks/mills-fields.toml`` (key
``fields``). For every set also the estimate's error at the half-hour advices, which see no new
sample (the state predicted over the half hour since the last one): their RMS and the RMS of each
run's mean of them (what the model's form adds the same way all along a run).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

#: the default filter's results files (``benchmarks/regenerate.py``)
FILES = ("hidden_mills", "hidden_mills_seed1_all", "hidden_mills_seed2_all", "hidden_mills_heldout",
         "hidden_mills_heldout_seed1")
#: the same mills and seeds with 1000-particle samples
FILES_1000 = tuple(f.replace("hidden_mills", "hidden_mills_samples1000", 1) for f in FILES)
#: the same with the operator taking the extra samples the advice asks for (``--sample-on-request``)
FILES_ON_REQUEST = tuple(f.replace("hidden_mills", "hidden_mills_onrequest", 1) for f in FILES)


#: the default controller on the mills drawn after it was final (``--mills benchmarks/mills-unseen.toml``)
FILES_UNSEEN = ("hidden_mills_unseen", "hidden_mills_unseen_seed1")
#: ... and on the mills that change card fields none of the others change (``benchmarks/mills-fields.toml``)
FILES_FIELDS = ("hidden_mills_fields", "hidden_mills_fields_seed1")


#: the idle rule's distance from the target (``hidden_mills.NEED_TOL``), also the controller's tolerance
NEED_TOL = 0.02
#: the longest idle stretch the benchmark's bar allows (h)
IDLE_BAR_H = 1.0


def rel_pct(est: float, plant: float) -> float:
    return 100.0 * (est - plant) / plant


def idle_stretches(case: dict) -> list[dict]:
    """Rests of a run's step log that began with the plant more than :data:`NEED_TOL` from the target:
    start, hours (to the next milling advice or the batch end), the plant's and the estimate's error
    against the target at the start (%). Whole advice intervals only (the benchmark's own count also
    takes the rest after a burst)."""
    steps, tgt = case["steps"], case.get("target_s_mean_um")
    if tgt is None or not steps or "mill_min" not in steps[0]:
        return []
    out, k = [], 0
    while k < len(steps):
        s = steps[k]
        if s["mill_min"] > 0 or abs(s["plant_s_mean_um"] - tgt) <= NEED_TOL * tgt:
            k += 1
            continue
        j = k
        while j + 1 < len(steps) and steps[j + 1]["mill_min"] == 0:
            j += 1
        end = steps[j + 1]["t_h"] if j + 1 < len(steps) else float(case["hours"])
        out.append({"t_h": s["t_h"], "hours": end - s["t_h"], "plant_error_pct": rel_pct(s["plant_s_mean_um"], tgt),
                    "estimate_error_pct": rel_pct(s["estimate_s_mean_um"], tgt)})
        k = j + 1
    return out


def run_rows(results: dict, name: str) -> list[dict]:
    """One row per case of a results file: final error and the estimate's errors (%)."""
    rows = []
    for c in results["cases"]:
        steps = c["steps"]
        last = steps[-1]
        at_samples = [rel_pct(s["estimate_s_mean_um"], s["plant_s_mean_um"]) for s in steps
                      if s["t_h"] > 0 and abs(s["t_h"] - round(s["t_h"])) < 1e-6]
        between = [rel_pct(s["estimate_s_mean_um"], s["plant_s_mean_um"]) for s in steps
                   if s["t_h"] > 1 and abs(s["t_h"] - round(s["t_h"])) > 1e-6]  # predicted since the last sample
        rows.append({"file": name, "case": c["case"], "final_error_pct": float(c["error_pct"]),
                     "estimate_error_last_advice_pct": rel_pct(last["estimate_s_mean_um"], last["plant_s_mean_um"]),
                     "last_advice_t_h": float(last["t_h"]), "estimate_errors_at_samples_pct": at_samples,
                     "estimate_errors_between_samples_pct": between,
                     "idle_over_bar": [r for r in idle_stretches(c) if r["hours"] > IDLE_BAR_H + 1e-9]})
    return rows


def summary(rows: list[dict]) -> dict:
    fin = np.array([r["final_error_pct"] for r in rows])
    est = np.array([r["estimate_error_last_advice_pct"] for r in rows])
    samp = np.concatenate([r["estimate_errors_at_samples_pct"] for r in rows])
    betw = np.concatenate([r["estimate_errors_between_samples_pct"] for r in rows])
    # a run's own mean error between samples: what the half hours since a sample add, the same way all along
    bias = np.array([np.mean(r["estimate_errors_between_samples_pct"]) for r in rows
                     if r["estimate_errors_between_samples_pct"]])
    rms = lambda a: float(np.sqrt(np.mean(np.square(a))))  # noqa: E731
    idle = [i for r in rows for i in r.get("idle_over_bar", [])]
    return {"runs": len(rows), "final_rms_pct": rms(fin), "estimate_last_advice_rms_pct": rms(est),
            "estimate_at_samples_rms_pct": rms(samp), "samples": int(samp.size),
            "estimate_between_samples_rms_pct": rms(betw), "between_samples": int(betw.size),
            "run_mean_between_samples_rms_pct": rms(bias),
            "last_advice_between_samples": sum(abs(r["last_advice_t_h"] - round(r["last_advice_t_h"])) > 1e-6
                                               for r in rows),
            "corr_final_vs_minus_estimate": float(np.corrcoef(fin, -est)[0, 1]),
            "left_rms_pct": rms(fin + est),
            "over_5pct": [f"{r['file']}:{r['case']}" for r in rows if abs(r["final_error_pct"]) > 5.0],
            "idle_over_bar": len(idle),
            "idle_over_bar_estimate_within_tol": sum(abs(i["estimate_error_pct"]) <= 100 * NEED_TOL for i in idle),
            "idle_over_bar_plant_error_abs_max_pct": max((abs(i["plant_error_pct"]) for i in idle), default=0.0)}


def figure(rec: dict, path: Path) -> Path:
    """Final error against minus the estimate's error at the last advice, one point per run, for each
    sample size in the file; the diagonal is a plan that steers its estimate exactly."""
    from bmctl.io import pyplot, savefig

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(4.8, 4.4))
    fams = [("300-particle samples", rec)] + [(label, rec[key]) for key, label in (
        ("samples1000", "1000-particle samples"), ("onrequest", "300, one more when asked")) if key in rec]
    lim = 0.0
    for (label, fam), (col, mark) in zip(fams, (("C0", "o"), ("C3", "^"), ("C2", "s"))):
        x = np.array([-r["estimate_error_last_advice_pct"] for r in fam["runs"]])
        y = np.array([r["final_error_pct"] for r in fam["runs"]])
        lim = max(lim, float(np.max(np.abs(np.concatenate([x, y])))))
        s = fam["summary"]
        ax.plot(x, y, mark, color=col, ms=5, alpha=0.8, mfc="none",
                label=f"{label}: final RMS {s['final_rms_pct']:.1f} %, r = {s['corr_final_vs_minus_estimate']:.2f}")
    lim = 1.1 * lim
    ax.plot([-lim, lim], [-lim, lim], "k-", lw=0.7, label="final error = minus the estimate's")
    ax.axhspan(-5, 5, color="0.9", zorder=0)
    ax.set_xlim(-lim, lim)
    ax.set_ylim(-lim, lim)
    ax.set_xlabel("minus the estimate's error at the last advice (%)", fontsize=8)
    ax.set_ylabel("final error of the mean size (%)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=6.5, loc="upper left")
    ax.set_title("hidden mills, every advice accepted (grey: within 5 %)", fontsize=8)
    fig.tight_layout()
    savefig(fig, path, dpi=110)
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--no-results", action="store_true", help="print only")
    ap.add_argument("--figure", metavar="PNG", help="draw results/hidden_mills_floor.json, run nothing")
    a = ap.parse_args()
    from bmctl.results import load_results, results_dir, write_results

    if a.figure:
        print("wrote", figure(load_results("hidden_mills_floor"), Path(a.figure)))
        return

    out, settings = {}, {"files": list(FILES)}
    for key, files in (("samples300", FILES), ("samples1000", FILES_1000), ("onrequest", FILES_ON_REQUEST),
                       ("unseen", FILES_UNSEEN), ("fields", FILES_FIELDS)):
        if key != "samples300" and not all((results_dir() / f"{f}.json").is_file() for f in files):
            print(f"{key}: not all of {', '.join(files)} in results/; left out")
            continue
        rows = []
        for name in files:
            rows += run_rows(load_results(name), name)
        s = summary(rows)
        for r in rows:
            print(f"{r['file']:<38} {r['case']}  final {r['final_error_pct']:+6.2f} %   "
                  f"estimate at the last advice {r['estimate_error_last_advice_pct']:+6.2f} %")
            for i in r["idle_over_bar"]:
                print(f"{'':<41}rest from {i['t_h']:g} h for {i['hours']:.1f} h: plant {i['plant_error_pct']:+.2f} %, "
                      f"estimate {i['estimate_error_pct']:+.2f} % from the target")
        print(f"{key}: {s['runs']} runs: final RMS {s['final_rms_pct']:.2f} %, estimate at the last advice RMS "
              f"{s['estimate_last_advice_rms_pct']:.2f} %, at the {s['samples']} hourly samples "
              f"{s['estimate_at_samples_rms_pct']:.2f} %; correlation of the final error with minus the "
              f"estimate's {s['corr_final_vs_minus_estimate']:.2f}; left over {s['left_rms_pct']:.2f} % RMS; "
              f"{s['idle_over_bar']} rests over {IDLE_BAR_H:g} h while needed, {s['idle_over_bar_estimate_within_tol']} "
              f"begun with the estimate within the tolerance\n")
        print(f"{key}: the estimate at the half-hour advices since the last sample: RMS "
              f"{s['estimate_between_samples_rms_pct']:.2f} % ({s['between_samples']}), each run's mean of them RMS "
              f"{s['run_mean_between_samples_rms_pct']:.2f} %; the last advice between samples in "
              f"{s['last_advice_between_samples']} of {s['runs']} runs\n")
        for r in rows:
            r.pop("estimate_errors_at_samples_pct"), r.pop("estimate_errors_between_samples_pct")
        if key == "samples300":
            out.update({"summary": s, "runs": rows})
        else:
            out[key] = {"summary": s, "runs": rows}
            settings[f"files_{key}"] = list(files)
    if not a.no_results:
        p = write_results("hidden_mills_floor", out, settings=settings,
                          command="python benchmarks/hidden_mills_floor.py")
        print(f"wrote {p}")


if __name__ == "__main__":
    main()
