"""Particle filter vs unscented Kalman filter: open-loop estimation study (and optional closed loop).

Run (the table of docs/estimation.md, section "UKF baseline"):

    python benchmarks/estimator_study.py --out out/estimator_study                 # open loop, 20 seeds
    python benchmarks/estimator_study.py --seeds 2 --hours 4 --out out/est_quick     # quick look
    python benchmarks/estimator_study.py --closed-loop --cl-seeds 1 --out out/estimator_study_cl

Open loop: for each scenario (scenarios/trial-mismatch.toml: plant gamma x1.3, delta x0.7;
scenarios/trial-target-size.toml: plant on the card) the stochastic PLANT (the scenario's
particles, 5000) runs the card's recipe (300 rpm continuous for the scenario's 12 h) with a
micrograph sample every ``sampling.every_h`` (1 h) through
:func:`bmctl.measure.sampler.micrograph_sample` (the scenario's segmentation noise) and a
vial-temperature reading. Every estimator variant (PF with the scenario's N = 1000 particles,
UKF with default settings) x sample size n (50, 100, 300 measured particles) sees the same
plant trajectory and, for equal n, the same samples. Truth: the plant's population moments at
the sample time; for gamma, delta the plant's factors relative to the card.

Closed loop (``--closed-loop``): :func:`bmctl.trial.run_trial` of each scenario with
``[estimator] kind = "pf"`` and ``"ukf"`` (the MPC of the scenario on each), ``--cl-seeds``
seeds each; reports the final |error| of the target moment.

Writes to --out: summary.md (the tables), runs.npz (open loop: every estimate and truth),
closed_loop.md (with --closed-loop).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's bmctl

import numpy as np  # noqa: E402

from bmctl.config import card_schedule, load_card, with_factors  # noqa: E402
from bmctl.estimate.filter import FilterSettings  # noqa: E402
from bmctl.estimate.likelihood import LawSettings  # noqa: E402
from bmctl.estimate.run import inputs_between, make_estimator  # noqa: E402
from bmctl.estimate.ukf import UKFSettings  # noqa: E402
from bmctl.scenario import load_scenario, resolve  # noqa: E402

SCENARIOS = ("scenarios/trial-mismatch.toml", "scenarios/trial-target-size.toml")
MOMENTS = ("s_mean_um", "s_std_um", "r_mean", "r_std")
KINDS = ("pf", "ukf")


def run_open_loop(scenario: str, seed: int, ns=(50, 100, 300), hours: float | None = None) -> dict:
    """One seeded open-loop run of every (estimator, n) variant on one plant trajectory.

    Returns
    -------
    dict
        ``t_h`` (K,), ``truth`` (K, 4), ``p_true`` (2,), and per label ``"<kind>-n<n>"``:
        ``mean``, ``q05``, ``q95`` (K, 8) and ``update_ms`` (K,).
    """
    from bmctl.measure.sampler import micrograph_sample
    from bmctl.moments.model import make_moment_model
    from bmctl.plant.plant import Plant
    from bmctl.plant.population import UM

    sc = load_scenario(scenario)
    base = Path(scenario).resolve().parent
    card = load_card(resolve(sc.model, base))
    model = make_moment_model(resolve(sc.model, base))
    hours = sc.hours if hours is None else hours
    p_true = np.array([sc.plant.gamma_factor, sc.plant.delta_factor])
    ss = np.random.SeedSequence([seed, 31])
    g_plant, g_est, g_samp = ss.spawn(3)
    plant = Plant(with_factors(card, *p_true), np.random.default_rng(g_plant), sc.plant.particles)
    segments = card_schedule(card, hours)
    times = np.arange(sc.sampling.every_h, hours + 1e-9, sc.sampling.every_h)
    est_seeds = g_est.spawn(len(ns))
    filters = {}
    for i, n in enumerate(ns):
        for kind, g in zip(KINDS, est_seeds[i].spawn(2)):
            settings = (FilterSettings(n_particles=sc.estimator.particles, law=LawSettings()) if kind == "pf"
                        else UKFSettings())
            filters[(kind, n)] = make_estimator(kind, model, np.random.default_rng(g), settings=settings)
    samp_rng = {n: np.random.default_rng(g) for n, g in zip(ns, g_samp.spawn(len(ns)))}
    out = {"t_h": times, "truth": np.zeros((times.size, 4)), "p_true": p_true}
    for kind, n in filters:
        out[f"{kind}-n{n}"] = {"mean": np.zeros((times.size, 8)), "q05": np.zeros((times.size, 8)),
                               "q95": np.zeros((times.size, 8)), "update_ms": np.zeros(times.size)}
    t_prev = 0.0
    for i, t in enumerate(times):
        pieces = inputs_between(segments, t_prev, t)
        for rpm, milling, h in pieces:
            plant.advance(rpm, h, milling)
        mo = plant.moments()
        out["truth"][i] = [mo[m] for m in MOMENTS]
        T_read = plant.temperature_C if sc.sampling.temperature_reading else None
        tabs = {n: micrograph_sample(plant.s / UM, plant.r, n, g, noise=sc.sampling.noise) for n, g in samp_rng.items()}
        for (kind, n), f in filters.items():
            for rpm, milling, h in pieces:
                f.predict((rpm, milling), h)
            t0 = time.perf_counter()
            e = f.update(tabs[n].s_um, tabs[n].r, temperature_c=T_read)
            rec = out[f"{kind}-n{n}"]
            rec["update_ms"][i] = (time.perf_counter() - t0) * 1e3
            rec["mean"][i], rec["q05"][i], rec["q95"][i] = e.mean, e.q05, e.q95
        t_prev = t
    return out


def metrics(runs: list[dict], label: str) -> dict:
    """Final and time-mean |ln(est / true)| (x100 ~ %) of the moments and of gamma, delta,
    90 % interval coverage (moments over all times; gamma, delta at the end), median update ms."""
    fin, avg, cov, pfin, pavg, pcov, ms = [], [], [], [], [], [], []
    for r in runs:
        rec, tr, pt = r[label], r["truth"], r["p_true"]
        e = np.abs(np.log(rec["mean"][:, :4] / tr))
        ep = np.abs(np.log(rec["mean"][:, 6:8] / pt[None, :]))
        fin.append(e[-1]), avg.append(e.mean(axis=0)), pfin.append(ep[-1]), pavg.append(ep.mean(axis=0))
        cov.append((rec["q05"][:, :4] <= tr) & (tr <= rec["q95"][:, :4]))
        pcov.append((rec["q05"][-1, 6:8] <= pt) & (pt <= rec["q95"][-1, 6:8]))
        ms.append(rec["update_ms"])
    return {"final": 100 * np.mean(fin, axis=0), "mean": 100 * np.mean(avg, axis=0),
            "p_final": 100 * np.mean(pfin, axis=0), "p_mean": 100 * np.mean(pavg, axis=0),
            "coverage": 100 * np.mean(np.concatenate(cov), axis=0), "p_coverage": 100 * np.mean(pcov, axis=0),
            "update_ms": float(np.median(np.concatenate(ms)))}


def summary_table(res: dict, ns, values: dict | None = None) -> str:
    """The open-loop table; every cell carries its results marker (``results/estimator_study.json``),
    and ``values`` (when given) receives the numbers under the same keys."""
    from bmctl.results import marked

    lines = ["| scenario | estimator | n | final error % (s_mean, s_std, r_mean, r_std) | mean error % (same) "
             "| gamma, delta final % | gamma, delta mean % | 90 % coverage % (4 moments) | gamma, delta final covered % "
             "| update ms (median) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for sc, runs in res.items():
        name = Path(sc).stem
        for n in ns:
            for kind in KINDS:
                m = metrics(runs, f"{kind}-n{n}")
                key = f"open_loop.{name}.{kind}.n{n}"
                rec = {k: (np.asarray(v).tolist() if not isinstance(v, float) else v) for k, v in m.items()}
                if values is not None:
                    values.setdefault("open_loop", {}).setdefault(name, {}).setdefault(kind, {})[f"n{n}"] = rec

                def f(k):
                    return ", ".join(marked("estimator_study", f"{key}.{k}.{i}", x, "{:.1f}") for i, x in enumerate(rec[k]))

                lines.append(f"| {name} | {kind} | {n} | {f('final')} | {f('mean')} | {f('p_final')} | "
                             f"{f('p_mean')} | {f('coverage')} | {f('p_coverage')} | "
                             f"{marked('estimator_study', key + '.update_ms', m['update_ms'], '{:.1f}')} |")
    return "\n".join(lines)


def _scenario_with_kind(scenario: str, kind: str, folder: Path) -> str:
    """A copy of the scenario with ``[estimator] kind``, its paths made absolute."""
    root = Path(scenario).resolve().parent.parent
    text = Path(scenario).read_text()
    text = text.replace('"models/', f'"{root}/models/').replace('"controllers/', f'"{root}/controllers/')
    if "[estimator]" in text:
        raise SystemExit(f"{scenario}: already has an [estimator] table; edit this helper")
    p = folder / f"{Path(scenario).stem}-{kind}.toml"
    p.write_text(text + f'\n[estimator]\nkind = "{kind}"\n')
    return str(p)


def closed_loop(scenarios, seeds, out: Path, kinds=KINDS) -> str:
    """MPC trials on each estimator; returns the markdown table of final target errors."""
    from bmctl.trial import run_trial

    out.mkdir(parents=True, exist_ok=True)
    rows = ["| scenario | estimator | seeds | final target error % (per seed) | mean ± se % | wall s per trial |",
            "|---|---|---|---|---|---|"]
    errs = {(scn, kind): [] for scn in scenarios for kind in kinds}
    walls = {key: [] for key in errs}
    paths = {(scn, kind): _scenario_with_kind(scn, kind, out) for scn, kind in errs}
    for seed in seeds:  # seeds outermost: a partial run covers every scenario and estimator
        for (scn, kind), path in paths.items():
            folder = out / f"{Path(scn).stem}-{kind}-s{seed}"
            t0 = time.perf_counter()
            if (folder / "summary.json").exists():
                import json

                summ = json.loads((folder / "summary.json").read_text())
            else:
                summ = run_trial(path, folder, seed=seed, resume=(folder / "checkpoint.npz").exists())
            walls[(scn, kind)].append(time.perf_counter() - t0)
            errs[(scn, kind)].append(100 * max(summ["final_error"].values()))
            print(f"  closed loop {Path(scn).stem} {kind} seed {seed}: {errs[(scn, kind)][-1]:.2f} % "
                  f"({walls[(scn, kind)][-1]:.0f} s)", flush=True)
    for (scn, kind), e in errs.items():
        se = np.std(e, ddof=1) / np.sqrt(len(e)) if len(e) > 1 else float("nan")
        rows.append(f"| {Path(scn).stem} | {kind} | {len(seeds)} | {', '.join(f'{v:.2f}' for v in e)} | "
                    f"{np.mean(e):.2f} ± {se:.2f} | {np.mean(walls[(scn, kind)]):.0f} |")
    return "\n".join(rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/estimator_study")
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--n", default="50,100,300", help="measured particles per sample, comma separated")
    ap.add_argument("--hours", type=float, default=None, help="shorter recipe (quick look); default: the scenario's")
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS))
    ap.add_argument("--closed-loop", action="store_true", help="also run MPC trials on each estimator (minutes each)")
    ap.add_argument("--cl-seeds", type=int, default=1)
    ap.add_argument("--cl-kinds", default=",".join(KINDS),
                    help="estimators of the closed loop, comma separated (pf,ukf); the PF trials equal the control "
                         "study's mpc-default runs of the same scenario and seed")
    ap.add_argument("--no-open-loop", action="store_true")
    ap.add_argument("--no-results", action="store_true", help="do not write results/estimator_study.json")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    ns = tuple(int(v) for v in args.n.split(","))
    text = [f"# Estimator study: particle filter vs UKF\n\ncommand: python benchmarks/estimator_study.py "
            f"{' '.join(sys.argv[1:] if argv is None else argv)}\n"]
    from bmctl import io

    if not args.no_open_loop:
        t0 = time.perf_counter()
        res = {scn: [] for scn in args.scenarios}
        for seed in range(args.seeds):  # seeds outermost: the partial summary covers every scenario
            for scn in args.scenarios:
                res[scn].append(run_open_loop(scn, seed, ns, args.hours))
                print(f"  open loop {Path(scn).stem} seed {seed} done ({time.perf_counter() - t0:.0f} s)", flush=True)
            done = seed + 1
            part = [f"## Open loop ({done} of {args.seeds} seeds, card's recipe, sample every hour; wall "
                    f"{time.perf_counter() - t0:.0f} s)\n", summary_table(res, ns) + "\n"]
            io.write_text(out / "summary.md", "\n".join(text + part))
        text += part
        values: dict = {}
        summary_table(res, ns, values)
        if not args.no_results:
            import os

            from bmctl.results import write_results

            write_results("estimator_study", dict(values, wall_s=time.perf_counter() - t0,
                                                  load_average=list(os.getloadavg())),
                          settings={"seeds": args.seeds, "n": list(ns), "hours": args.hours,
                                    "scenarios": [Path(x).stem for x in args.scenarios]},
                          command=f"python benchmarks/estimator_study.py --seeds {args.seeds}")
        flat = {}
        for scn, runs in res.items():
            for k, r in enumerate(runs):
                for key, v in r.items():
                    if isinstance(v, dict):
                        for kk, vv in v.items():
                            flat[f"{Path(scn).stem}/{k}/{key}/{kk}"] = vv
                    else:
                        flat[f"{Path(scn).stem}/{k}/{key}"] = v
        np.savez_compressed(out / "runs.npz", **flat)
    if args.closed_loop:
        t0 = time.perf_counter()
        kinds = tuple(k for k in args.cl_kinds.split(",") if k)
        if not kinds or set(kinds) - set(KINDS):
            raise SystemExit(f"--cl-kinds: expected a comma-separated subset of {','.join(KINDS)}, got {args.cl_kinds!r}")
        cl = closed_loop(args.scenarios, list(range(args.cl_seeds)), out / "closed_loop", kinds)
        text.append(f"## Closed loop (MPC on each estimator; wall {time.perf_counter() - t0:.0f} s)\n\n{cl}\n")
    io.write_text(out / "summary.md", "\n".join(text))
    print("\n".join(text))
    return 0


if __name__ == "__main__":
    sys.exit(main())
