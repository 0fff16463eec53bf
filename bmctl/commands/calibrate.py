"""Calibrate a card's parameters to measured micrograph series, the stochastic plant as the simulator.

``bmctl calibrate CARD.toml HISTORY.toml... --params alpha,beta,gamma,delta`` fits the named card
parameters to the (s, r) samples of one or more histories (what the mill ran and what was
measured when) and writes ``DIR/<card>-calibrated.toml`` with its moment coefficients
(``<card>-calibrated.moments.toml``, identified on the spot), ``DIR/calibration.json`` (estimates,
90 % intervals, the fit at the optimum, what the data do not identify) and one histogram
figure per history. Plant runs go through Dask (a local cluster by default, ``--scheduler``
for a running one). See docs/calibration-from-data.md.
"""

from __future__ import annotations

import sys
import time

from ..naming import naming
from ._args import LIBRARY_FLAGS, int_arg, output_path, progress_bar


def configure(p):
    p.add_argument("model", metavar="CARD.toml", help="starting model card (also the mill and the prior centre)")
    p.add_argument("histories", metavar="HISTORY.toml", nargs="+",
                   help="schedule (file or [[segment]]) and [[sample]] t_h with table= or image= (+ um_per_px)")
    p.add_argument("--params", default="alpha,beta,gamma,delta", metavar="P1,P2,...",
                   help="card parameters to fit: alpha, beta, gamma, delta or section.field (default the four factors)")
    p.add_argument("--seed", type=int_arg("--seed", 0), default=0, help="random seed (default 0)")
    p.add_argument("--out", default="out/calibrate", metavar="DIR", help="output folder (default out/calibrate)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS", help="a running dask scheduler (tcp://host:8786)")
    p.add_argument("--workers", type=int_arg("--workers", 0, 4096), default=None,
                   help="local Dask worker processes (default: the machine's CPUs; 0 or 1: serial, no Dask; not with "
                        "--scheduler, whose workers run the plants)")
    p.add_argument("--particles", type=int_arg("--particles", 100, 10**6), default=2000,
                   help="simulated particles per plant run (default 2000)")
    p.add_argument("--replicates", type=int_arg("--replicates", 2, 64), default=2,
                   help="common-random-number plant runs per design point (default 2)")
    p.add_argument("--no-moment-start", action="store_true", help="start from the card, not the moment model's fit")
    p.add_argument("--accept-unusable", action="store_true",
                   help="use an image whose measurement verdict is unusable (refused by default, as bmctl estimate does)")


@naming({**LIBRARY_FLAGS, "names": "--params"})  # the library's refusals name this command's flags
def run(args) -> int:
    from tqdm import tqdm

    from ..calibrate.fit import FitSettings
    from ..calibrate.history import load_history
    from ..calibrate.params import parse_params
    from ..calibrate.run import run_calibration
    from ..config import load_card
    from ..io import name_part
    from ..parallel import cap_workers, check_engine_args, client_for, close_client

    check_engine_args(args.workers, args.scheduler)
    out = output_path(args.out)
    card = load_card(args.model)
    names = parse_params(args.params, card)
    refuse_same_file(args.histories)  # before any image is measured
    histories = [load_history(h, card, args.accept_unusable) for h in args.histories]
    seen = set()
    for h in histories:  # each history's figure is named by its name as a file name part (bmctl.io.name_part)
        if name_part(h.name) in seen:
            raise_dup(h)
        seen.add(name_part(h.name))
    refuse_output_onto_input(out, args.model, histories)
    from ..calibrate.history import size_range_warnings

    for h in histories:  # doubtful images and sizes the card does not cover: once every history is read
        for w in h.warnings + size_range_warnings(card, [(f"{h.path}: sample[{k}]", s.t_h, s.s_um)
                                                            for k, s in enumerate(h.samples)]):
            print(f"bmctl: warning: {w}", file=sys.stderr)
    settings = FitSettings(particles=args.particles, replicates=args.replicates)
    from ..work import add, calibrate_work, check_work, identify_work

    check_work(add(calibrate_work(card, histories, len(names), args.particles, args.replicates, settings.max_iter),
                   identify_work(card, args.seed)), "--particles/--replicates/HISTORY.toml (and the calibrated "
               "card's identification)")
    runs_at_once = (2 * len(names) + 1) * args.replicates * len(histories)  # a central-difference Jacobian's runs
    workers = args.workers if args.workers is None else cap_workers(args.workers, runs_at_once)
    client = client_for(args.scheduler, workers)
    bar = progress_bar(desc="plant runs", unit="run", total=None)
    t0 = time.perf_counter()
    try:
        res = run_calibration(card, args.model, histories, names, out, seed=args.seed, settings=settings,
                              client=client, moment_stage=not args.no_moment_start, progress=bar.update,
                              on_iteration=lambda e: bar.set_postfix(it=e["iteration"], chi2=f"{e['chi2']:.1f}"),
                              log=lambda msg: tqdm.write(f"identify (the calibrated card's moment coefficients): {msg}",
                                                         file=sys.stderr))
    finally:
        bar.close()
        close_client(client)
    cal = res.calibration
    engine = "serial" if client is None else ("scheduler " + args.scheduler if args.scheduler else "local Dask")
    n_samples = sum(len(h.samples) for h in histories)
    print(f"{card.card.name}: {count(len(histories), 'history', 'histories')}, {count(n_samples, 'sample')}; "
          f"{count(cal.plant_runs, 'plant run')} ({engine}) in {res.wall_s:.0f} s, "
          f"{time.perf_counter() - t0:.0f} s with the calibrated card's moment identification; chi2 {cal.chi2:.1f} at the estimate on "
          f"{count(cal.n_summaries, 'summary', 'summaries')}{'' if cal.converged else ' (not converged)'}")
    if not cal.converged:
        print(f"  {cal.stop_reason}")
        print(f"bmctl: note: calibration {cal.stop_reason}", file=sys.stderr)
    for i in range(len(cal.names)):
        print(estimate_line(cal, i))
    for p in res.paths:
        print(f"  wrote {p}")
    for p in res.removed:
        print(f"  removed {p} (a figure of the earlier calibration in this folder; no history of this one)")
    return 0


def count(n: int, one: str, many: str | None = None) -> str:
    """``n`` and the noun, singular for 1 (``1 history``, ``2 histories``).

    Examples
    --------
    >>> count(1, "history", "histories"), count(2, "history", "histories"), count(0, "sample")
    ('1 history', '2 histories', '0 samples')
    """
    return f"{n} {one if n == 1 else (many or one + 's')}"


def estimate_line(cal, i: int) -> str:
    """One fitted parameter: estimate and 90 % interval in its unit, ratio to the card, identified or not.

    Parameters
    ----------
    cal : bmctl.calibrate.fit.Calibration
    i : int
        The parameter's index in ``cal.names``.
    """
    from ..calibrate.params import param_unit

    unit = param_unit(cal.names[i])
    u = f" {unit}" if unit else ""
    flag = "" if cal.identified[i] else "  NOT IDENTIFIED"
    return (f"  {cal.names[i]:28s} {cal.values[i]:.4g}{u}  90 % [{cal.lo90[i]:.4g}, {cal.hi90[i]:.4g}]{u}  "
            f"x{cal.values[i] / cal.card_values[i]:.2f} of the card{flag}")


def refuse_same_file(paths) -> None:
    """One line when a history file is given twice, by the same path, a symbolic or a hard link (it
    would be fitted twice, its figure named twice)."""
    from ..errors import InputError
    from ..io import repeated_file

    pair = repeated_file(paths)
    if pair is not None:
        raise InputError(f"{paths[pair[1]]}: this history file is given twice (also as {paths[pair[0]]}); "
                         "give each once")


def refuse_output_onto_input(out, card_path, histories) -> None:
    """One line when a file the calibration writes in ``out`` (the calibrated card, its moment
    coefficients, ``calibration.json``, a history's figure) is one of its inputs (the card, its
    coefficients, a history, its schedule file or a sample): the input would be replaced.

    Parameters
    ----------
    out : path-like
        The output folder.
    card_path : path-like
        The starting card.
    histories : list of bmctl.calibrate.history.History
    """
    from pathlib import Path

    from ..io import same_file
    from ..errors import InputError
    from ..io import name_part
    from ..moments.coeffs import coeffs_path

    out = Path(out)
    card_out = out / f"{Path(card_path).stem}-calibrated.toml"
    outputs = [card_out, coeffs_path(card_out), out / "calibration.json",
               *(out / f"histograms-{name_part(h.name)}.png" for h in histories)]
    inputs = [Path(card_path), coeffs_path(card_path)]
    for h in histories:
        inputs += [Path(h.path), *([Path(h.schedule)] if h.schedule else []), *(Path(s.source) for s in h.samples)]
    for o in outputs:
        for i in inputs:
            if same_file(o, i):
                raise InputError(f"--out: the calibration writes {o}, which is an input of this run ({i}); it would "
                                 "be replaced (choose another --out folder)")


def raise_dup(h):
    from ..errors import InputError

    raise InputError(f"{h.path}: name: history name {h.name!r} is used twice, or gives the same figure name as another "
                     "(give each history its own name)")
