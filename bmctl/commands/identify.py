"""Fit the moment model to plant experiments and validate it on held-out schedules.

Runs a design of plant experiments (speeds across the mill's range, interrupted milling,
steps, rests, branches from other states, random schedules) on a seeded ensemble, fits
the free coefficients by least squares, validates on held-out random schedules and writes
``models/<card-name>.moments.toml`` next to the card (or ``--out``). Every run starts from
the built-in defaults, so re-running regenerates the file from the current card and plant.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path

from ..errors import InputError
from ._args import int_arg, output_path




def configure(p):
    p.add_argument("model", metavar="MODEL.toml", help="model card (see models/)")
    p.add_argument("--seed", type=int_arg("--seed", 0), default=0, help="seed of the plant ensemble and the design (default 0)")
    p.add_argument("--out", default=None, metavar="FILE",
                   help="coefficient file (default: models/<card-name>.moments.toml next to the card)")
    p.add_argument("--particles", type=int_arg("--particles", 200, 1_000_000), default=None,
                   help="simulated particles per plant (default 4000; --quick 2000)")
    p.add_argument("--random-schedules", type=int_arg("--random-schedules", 0, 200), default=None, metavar="N",
                   help="random schedules in the training design (default 16; --quick 2); 32 fits the shape "
                        "entries a little better at 1.5x the time (docs/moments.md, Sec. 6)")
    p.add_argument("--quick", action="store_true", help="fewer experiments, one training seed (about 4x faster)")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    p.add_argument("--figures", default=None, metavar="DIR",
                   help="also write validation.png (model vs plant on held-out schedules) and nrmse.png here")


def _out_path(args) -> Path:
    from ..moments.coeffs import coeffs_path

    out = output_path(args.out if args.out is not None else coeffs_path(args.model), folder=False)
    if out.suffix != ".toml":
        raise InputError(f"--out: {out} must end in .toml")
    if not out.parent.exists():
        raise InputError(f"--out: folder {out.parent} does not exist")
    return out


def run(args) -> int:
    import numpy as np

    from ..config import load_card
    from ..io import write_text
    from ..moments import identify as ident
    from ..moments.coeffs import toml_text
    from ..moments.model import default_coeffs, MomentModel

    card = load_card(args.model)
    out = _out_path(args)
    figs = output_path(args.figures, "--figures") if args.figures is not None else None
    particles = args.particles or (2000 if args.quick else 4000)
    train_seeds = [1000 * args.seed + k for k in ((1,) if args.quick else ident.TRAIN_SEEDS)]
    valid_seeds = [1000 * args.seed + k for k in ((11, 12) if args.quick else ident.VALID_SEEDS)]
    t0 = time.time()

    def log(msg):
        if not args.quiet:
            print(f"[{time.time() - t0:6.1f} s] {msg}", file=sys.stderr, flush=True)

    specs = ident.design(card, args.seed, args.quick, args.random_schedules)
    vspecs = ident.validation_design(card, args.seed, 4 if args.quick else ident.N_VALID)
    log(f"{card.card.name}: {len(specs)} training experiments x {len(train_seeds)} seeds, "
        f"{len(vspecs)} held-out schedules x {len(valid_seeds)} seeds, M={particles}")
    train = ident.run_experiments(card, specs, train_seeds, particles)
    log("training experiments done")
    valid = ident.run_experiments(card, vspecs, valid_seeds, particles)
    off = ident.run_experiments(card, ident.off_card_design(card), valid_seeds, particles)
    log("held-out experiments done")

    model0 = MomentModel(card, default_coeffs(card), "defaults")
    res = ident.fit(model0, train, log=log)
    model = MomentModel(card, res.coeffs, str(out))
    _check_finite(args.model, train + valid + off, res.coeffs)
    tab0 = ident.nrmse_table(model0, valid)
    tab = ident.nrmse_table(model, valid)
    tab_train = ident.nrmse_table(model, train)
    # off-card check: the model told the plant's (gamma, delta) factors, and not told (p = 1)
    otab = ident.nrmse_table(model, off)
    otab1 = ident.nrmse_table(model, [replace(e, p=np.ones(2)) for e in off])
    log("validation done")

    names = ident.MOMENTS[:5]
    report = _report(card.card.name, names, tab0, tab, tab_train) + "\n" + _report_off_card(names, otab1, otab)
    validation = {
        "definition": "NRMSE = RMSE(model - plant ensemble mean) / range of the plant-mean trajectory "
                      "(floored at 10 % of its mean), per held-out schedule; mean and max over schedules",
        "schedules": len(valid), "seeds": valid_seeds, "particles": particles,
        "mean": {k: round(float(v), 5) for k, v in zip(names, tab["mean"])},
        "max": {k: round(float(v), 5) for k, v in zip(names, tab["max"])},
        "defaults_mean": {k: round(float(v), 5) for k, v in zip(names, tab0["mean"])},
    }
    validation["off_card"] = _per_run(otab, names[:4])
    validation["off_card_p1"] = _per_run(otab1, names[:4])
    meta = {
        "card": card.card.name,
        "command": f"bmctl identify {args.model} --seed {args.seed}" + (" --quick" if args.quick else "")
                   + (f" --particles {args.particles}" if args.particles else "")
                   + (f" --random-schedules {args.random_schedules}" if args.random_schedules is not None else ""),
        "date_utc": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "experiments": len(train), "train_seeds": train_seeds, "particles": particles,
        "dt_h": ident.DT_H, "cost_initial": round(res.cost0, 6), "cost_final": round(res.cost, 6),
        "evaluations": res.nfev, "fit_seconds": round(res.seconds, 1),
    }
    text = toml_text(res.coeffs, {"identification": meta, "validation": validation},
                     header=f"Moment-model coefficients of {card.card.name}, written by `bmctl identify`.\n"
                            "Re-run the command in [identification] to regenerate; docs/moments.md explains them.")
    write_text(out, text)
    print(report)
    if figs is not None:
        from .. import plots

        label = f"{card.card.name}: moment model vs plant, held-out schedules"
        plots.identify_validation(figs / "validation.png", valid, tab["preds"], tab["rows"], label)
        plots.identify_nrmse(figs / "nrmse.png", tab["rows"], tab0["rows"], label)
        print(f"wrote {figs / 'validation.png'}, {figs / 'nrmse.png'}")
    print(f"wrote {out} ({time.time() - t0:.0f} s)")
    return 0


def _check_finite(model_path, experiments, coeffs) -> None:
    for e in experiments:
        if not all(math.isfinite(v) for v in e.Y.ravel()):
            raise InputError(f"{model_path}: the plant produced non-finite moments in {e.name}")
    if not all(math.isfinite(v) for v in coeffs.values()):
        raise InputError(f"{model_path}: identification produced non-finite coefficients")


def _per_run(tab, names) -> dict:
    """{"<run>, <moment>": NRMSE} for the held-out runs of an nrmse_table."""
    return {f"{n}, {k}": round(float(v), 5) for n, row in zip(tab["names"], tab["rows"]) for k, v in zip(names, row)}


def _report_off_card(names, tab0, tab) -> str:
    w = max(len(n) for n in tab["names"]) + 2
    lines = ["off-card plants (gamma, delta off the card; nothing fitted on them): NRMSE with p = (1, 1) -> "
             "with p = the plant's factors",
             f"{'recipe run':<{w}}" + "".join(f"{n:>22s}" for n in names[:4])]
    for n, r0, r1 in zip(tab["names"], tab0["rows"], tab["rows"]):
        lines.append(f"{n:<{w}}" + "".join(f"{100 * a:10.1f}% ->{100 * b:6.1f}%" for a, b in zip(r0[:4], r1[:4])))
    return "\n".join(lines)


def _report(name, names, tab0, tab, tab_train) -> str:
    w = max(len(n) for n in tab["names"]) + 2
    head = "".join(f"{n:>15s}" for n in names)
    lines = [f"{name}: NRMSE on held-out schedules (model vs plant ensemble mean)",
             f"{'schedule':<{w}}{head}"]
    for n, row in zip(tab["names"], tab["rows"]):
        lines.append(f"{n:<{w}}" + "".join(f"{100 * v:14.1f}%" for v in row[:5]))
    lines.append(f"{'mean':<{w}}" + "".join(f"{100 * v:14.1f}%" for v in tab["mean"][:5]))
    lines.append(f"{'max':<{w}}" + "".join(f"{100 * v:14.1f}%" for v in tab["max"][:5]))
    lines.append(f"{'mean, defaults':<{w}}" + "".join(f"{100 * v:14.1f}%" for v in tab0["mean"][:5]))
    lines.append(f"{'mean, training':<{w}}" + "".join(f"{100 * v:14.1f}%" for v in tab_train["mean"][:5]))
    lines.append(_target_line(names, tab["mean"]))
    return "\n".join(lines)


#: issue 3's validation target: mean NRMSE over the held-out schedules, per moment
TARGET_NRMSE = 0.05


def _target_line(names, mean) -> str:
    """The verdict on the target, naming each moment that misses it and by how much.

    >>> _target_line(["s_mean_um", "r_mean", "r_std"], [0.032, 0.0551, 0.0522])  # doctest: +NORMALIZE_WHITESPACE
    'target <= 5 % on every moment (mean over schedules): NOT met: r_mean 5.5 % (+0.5 points),
     r_std 5.2 % (+0.2 points); why: docs/moments.md, Sec. 6'
    >>> _target_line(["s_mean_um"], [0.032])
    'target <= 5 % on every moment (mean over schedules): met'
    """
    head = f"target <= {100 * TARGET_NRMSE:g} % on every moment (mean over schedules): "
    misses = [(n, float(v)) for n, v in zip(names, mean) if not float(v) <= TARGET_NRMSE]
    if not misses:
        return head + "met"

    def miss(n, v):
        d = 100 * (v - TARGET_NRMSE)
        digits = 2 if d < 0.1 else 1  # a miss by 0.04 points must not read "+0.0"
        return f"{n} {100 * v:.{digits}f} % (+{d:.{digits}f} points)"

    parts = ", ".join(miss(n, v) for n, v in misses)
    return head + "NOT met: " + parts + "; why: docs/moments.md, Sec. 6"
