"""Run a real mill as a campaign: log what ran, add measured samples, get and decide on advice.

``bmctl campaign init DIR --model CARD --target d50_um=45 [--controller CONFIG]`` starts one;
``log``, ``sample``, ``advise``, ``decide``, ``status`` and ``report`` work on it. Everything is
kept in ``DIR/campaign.sqlite`` (docs/campaign.md).
"""

from __future__ import annotations

import argparse
import json
import sys

from ._args import (DEFAULT_CONTROLLER, LIBRARY_FLAGS, controller_path, float_arg, hours_arg, int_arg, output_path,
                    rpm_arg)
from ._model import add_identify_flag, progress_printer, warn_window

#: ``init --particles``: equals :data:`bmctl.campaign.workflow.PARTICLES_RANGE` (a test checks), kept here so
#: that building the parser does not import the campaign's numerical modules
PARTICLES_RANGE = (50, 200_000)

#: the verbs' arguments (:func:`bmctl.naming.arg`) as this command's flags: the verbs run under this
#: table (and :data:`~bmctl.commands._args.LIBRARY_FLAGS`, for what they pass on to the measurement and
#: the moment model), so their messages name the flags (``--hours``), as from Python the arguments (``hours``)
FLAGS = {"target": "--target", "hours": "--hours", "temperature_max_c": "--temperature-max-c",
         "particles": "--particles", "rpm": "--rpm", "milling": "--milling", "temperature_c": "--temperature-c",
         "from_h": "--from-h", "at_h": "--at-h", "um_per_px": "--um-per-px",
         "accept_unusable=True": "--accept-unusable", "accept=False": "--reject", "out": "--out",
         "seed": "--seed"}


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the ``campaign`` sub-verbs."""
    sub = parser.add_subparsers(dest="verb", metavar="VERB", parser_class=type(parser))
    sub.required = True
    p = sub.add_parser("init", help="start a campaign in DIR")
    p.add_argument("dir", metavar="DIR", help="a new campaign folder (campaign.sqlite and inputs/ are written there)")
    p.add_argument("--model", required=True, metavar="CARD", help="model card (models/*.toml)")
    p.add_argument("--controller", default=None, metavar="CONFIG",
                   help=f"controller config (controllers/*.toml; default {DEFAULT_CONTROLLER})")
    p.add_argument("--target", required=True, metavar="K=V[,K=V]",
                   help="target at the batch end, e.g. d50_um=45 or s_mean_um=40,r_mean=0.05")
    p.add_argument("--hours", type=hours_arg("--hours"), default=None, help="batch length (h); default: the card's")
    p.add_argument("--temperature-max-c", type=float_arg("--temperature-max-c"), default=None, metavar="C",
                   help="vial-temperature ceiling (°C); default: the controller's")
    p.add_argument("--seed", type=int_arg("--seed", 0), default=0, help="seed of the estimator (default: 0)")
    p.add_argument("--particles", type=int_arg("--particles", *PARTICLES_RANGE), default=1000,
                   help=f"filter particles, {PARTICLES_RANGE[0]} to {PARTICLES_RANGE[1]} (default: 1000)")
    p.add_argument("--energy-mult", action=argparse.BooleanOptionalAction, default=True,
                   help="the filter also learns energy_mult, the mill's impact energy per particle against the card's "
                        "(a mill whose balls or powder mass the card does not describe); --no-energy-mult: "
                        "gamma_mult, delta_mult only (default: on)")
    p.add_argument("--moment-noise-at", choices=("update", "sample"), default="update",
                   help="when the filter draws the moments' deferred model noise: at every update, a vial "
                        "reading alone included (update, the default), or only at a micrograph sample, whose "
                        "guided proposal draws it (sample; docs/estimation.md)")
    add_identify_flag(p)
    p = sub.add_parser("log", help="record what the mill ran")
    p.add_argument("dir", metavar="DIR", help="the campaign folder (campaign.sqlite and inputs/)")
    p.add_argument("--rpm", required=True, type=rpm_arg("--rpm"), help="sun-disc speed (0: a rest, no milling)")
    p.add_argument("--hours", required=True, type=hours_arg("--hours"), help="length of the interval (h)")
    p.add_argument("--milling", type=float_arg("--milling", 0, 1), default=1.0,
                   help="share of the interval spent milling, first (the rest of it is a rest; 0: a rest)")
    p.add_argument("--temperature-c", type=float_arg("--temperature-c"), default=None, metavar="C",
                   help="vial temperature read at the end of the interval (°C; enters the estimate, sigma 2 °C)")
    p.add_argument("--from-h", type=hours_arg("--from-h", zero=True), default=None, metavar="H",
                   help="start of the interval (default: end of the last one); overlaps and gaps are refused")
    p = sub.add_parser("sample", help="measure a sample and update the estimate")
    p.add_argument("dir", metavar="DIR", help="the campaign folder (campaign.sqlite and inputs/)")
    p.add_argument("--at-h", required=True, type=hours_arg("--at-h", zero=True), metavar="H", help="batch time the sample was taken (h)")
    p.add_argument("inputs", nargs="+", metavar="IMAGE_OR_TABLE", help="micrographs and/or particle tables (.csv)")
    p.add_argument("--um-per-px", type=float_arg("--um-per-px", 0, strict=True), default=None, metavar="X",
                   help="pixel size (overrides the image metadata)")
    p.add_argument("--scale-bar-um", type=float_arg("--scale-bar-um", 0, strict=True), default=None, metavar="L",
                   help="length written on the images' scale bar (µm): the pixel size from the bar found "
                        "(as bmctl measure)")
    p.add_argument("--accept-unusable", action="store_true",
                   help="use images whose measurement verdict is unusable (default: refused)")
    p = sub.add_parser("advise", help="estimate, recommended next action, plan to the batch end, and why")
    p.add_argument("dir", metavar="DIR", help="the campaign folder (campaign.sqlite and inputs/)")
    p.add_argument("--json", action="store_true", help="print the advice as JSON")
    add_identify_flag(p)
    p = sub.add_parser("decide", help="accept or reject the latest advice")
    p.add_argument("dir", metavar="DIR", help="the campaign folder (campaign.sqlite and inputs/)")
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--accept", action="store_true", help="the advice is run as recommended")
    g.add_argument("--reject", action="store_true",
                   help="the advice is not run; --rpm/--milling may say what is run instead")
    p.add_argument("--rpm", type=rpm_arg("--rpm"), default=None, help="with --reject: what will be run instead")
    p.add_argument("--milling", type=float_arg("--milling", 0, 1), default=None, help="with --reject: milling share instead (0-1; default: not stated)")
    p.add_argument("--note", default="", help="free text kept with the decision")
    p = sub.add_parser("status", help="where the campaign stands")
    p.add_argument("dir", metavar="DIR", help="the campaign folder (campaign.sqlite and inputs/)")
    p.add_argument("--json", action="store_true", help="print the status as JSON")
    p = sub.add_parser("report", help="self-contained HTML report")
    p.add_argument("dir", metavar="DIR", help="the campaign folder (campaign.sqlite and inputs/)")
    p.add_argument("--out", default=None, metavar="HTML", help="default DIR/report.html")


def _band(est: dict, k: str, fmt: str = "{:.4g}") -> str:
    v, lo, hi = est.get(k), est.get(f"{k}_q05"), est.get(f"{k}_q95")
    if v is None:
        return "n/a"
    s = fmt.format(v)
    return s + (f"  [{fmt.format(lo)}, {fmt.format(hi)}]" if lo is not None else "")


#: the estimate's quantities as printed by ``status``, ``sample`` and ``advise`` (the JSON holds the same numbers)
ESTIMATE_KEYS = ("s_mean_um", "s_std_um", "r_mean", "r_std", "d50_um", "temperature_c", "thermal_gain",
                 "gamma_mult", "delta_mult", "energy_mult")


def _estimate_lines(est: dict) -> list[str]:
    return [f"  {k:<14} {_band(est, k)}" for k in ESTIMATE_KEYS if k in est]


def _print_advice(a: dict) -> None:
    from ..campaign.advice import cooling_now, reach_line

    nx = a["next"]
    print(f"advice at t = {a['t_h']:g} h (plan {a['plan_id']}; {a['solver']}; advise {a['advise_ms']:.0f} ms)")
    for w in a.get("warnings", []):
        print(f"warning: {w}")
    print("estimate (mean [90 % interval]):")
    print("\n".join(_estimate_lines(a["estimate"])))
    tgt = ", ".join(f"{k} = {v:g}" for k, v in a["target"].items())
    ctl = ", ".join(f"{k} = {v:.4g}" for k, v in a["controller_target"].items())
    print(f"target: {tgt}" + (f"  (controller tracks {ctl})" if ctl != tgt else ""))
    if nx["interval_h"] <= 0:
        print("next: batch finished")
    else:
        print(f"next: {nx['rpm']:g} rpm, mill {nx['mill_min']} min, rest {nx['rest_min']} min "
              f"(interval {nx['interval_h'] * 60:.0f} min)")
    if a["schedule"]:
        held = any(not r["planned"] for r in a["schedule"])
        print("planned schedule to the batch end" + (" (from the controller's horizon on: its last input held):"
                                                      if held else ":"))
        for r in a["schedule"]:
            mark = "" if r["planned"] else "  (held)"
            print(f"  {r['t0_h']:6.2f}-{r['t1_h']:6.2f} h  {r['rpm']:6.0f} rpm  mill {r['mill_min']:3d} min  "
                  f"rest {r['rest_min']:3d} min{mark}")
    if a["end"]:
        print(f"predicted at the batch end (median [90 % band]):")
        for k in ("s_mean_um", "s_std_um", "r_mean", "d50_um", "temperature_c"):
            e = a["end"][k]
            print(f"  {k:<14} {e['median']:.4g}  [{e['q05']:.4g}, {e['q95']:.4g}]")
    for k, ok in a["reachable"].items():
        print("why: " + reach_line(k, a["target"][k], a["end"].get(k), ok, cooling_now(a["binding"])))
    print("binding: " + ("; ".join(a["binding"]) if a["binding"] else "no constraint binds"))
    for n in a.get("notes", []):
        print(f"note: {n}")
    if a.get("sample_first"):
        print(f"sample first: {a['sample_first']} (then advise again)")
    if a["pending_samples"]:
        print(f"note: {a['pending_samples']} sample(s) after the logged time wait for the log to reach them")
    sm = a.get("sampling")
    if sm:
        more = (f"; about {sm['particles_for_tolerance']} particles would read it within the "
                f"{sm['tolerance_pct']:g} % tolerance" if sm["particles"] < sm["particles_for_tolerance"] else "")
        what = (f"the sample at {sm['t_h']:g} h ({sm['particles']} particles) reads" if sm.get("samples", 1) == 1 else
                f"the {sm['samples']} samples at {sm['t_h']:g} h ({sm['particles']} particles together) read")
        print(f"sampling: {what} the mean size to ±{sm['mean_95_pct']:.1f} % (95 %){more}")


def run(args: argparse.Namespace) -> int:
    """Dispatch the sub-verb; print what it did. Its refusals name the flags (:data:`FLAGS`,
    :data:`~bmctl.commands._args.LIBRARY_FLAGS`). An SQLite error the checks did not foresee (a file
    damaged under a running command; an ``init`` whose new database SQLite cannot write) is one line
    naming the database."""
    import sqlite3

    from ..campaign.db import db_path
    from ..errors import InputError
    from ..naming import naming

    try:
        with naming({**LIBRARY_FLAGS, **FLAGS}):
            return _run(args)
    except sqlite3.DatabaseError as exc:
        if args.verb == "init":  # a new database (init removed what it made): nothing was damaged
            raise InputError(f"{db_path(args.dir)}: cannot be written as a campaign database ({exc})") from None
        raise InputError(f"{db_path(args.dir)}: damaged campaign database ({exc})") from None


def _estimator_changes(args: argparse.Namespace, cp) -> dict | None:
    """The filter settings ``init`` records: None (the campaign default) unless a flag changes them."""
    if args.energy_mult and args.moment_noise_at == "update":
        return None
    base = cp.CAMPAIGN_FILTER if args.energy_mult else cp.TWO_MULT_FILTER
    return base if args.moment_noise_at == "update" else {**base, "moment_noise_at": args.moment_noise_at}


def _run(args: argparse.Namespace) -> int:
    from .. import campaign as cp
    from ..campaign import targets as tg
    from ..errors import InputError

    v, d = args.verb, args.dir
    if d == "":  # Path("") is the current folder
        raise InputError("DIR: empty path")
    if getattr(args, "out", None) is not None:
        output_path(args.out, "--out", folder=False)
    if v == "init":
        meta = cp.init(d, args.model, controller_path(args.controller), tg.parse(args.target), hours=args.hours,
                       temperature_max_c=args.temperature_max_c, seed=args.seed, particles=args.particles,
                       identify=args.identify, progress=progress_printer(),
                       estimator=_estimator_changes(args, cp))
        print(f"campaign: {d}: {meta['hours']:g} h batch, target "
              + ", ".join(f"{k} = {x:g}" for k, x in meta["target"].items())
              + f", controller {meta['controller_kind']}; inputs copied to {d}/inputs")
    elif v == "log":
        r = cp.log(d, args.rpm, args.hours, args.milling, args.temperature_c, args.from_h)
        from ..campaign.readings import interval_text

        what = interval_text(r["rpm"], r["milling"], r["t1_h"] - r["t0_h"])
        print(f"logged {r['t0_h']:g}-{r['t1_h']:g} h: {what}"
              + (f"; vial {args.temperature_c:g} °C at the end" if args.temperature_c is not None else ""))
        if r["deviation"]:
            print(r["deviation"])
        for w in r["warnings"]:
            print(f"warning: {w}")
        est = r["estimate"]
        print(f"estimate at {est['t_h']:g} h: s_mean_um {_band(est, 's_mean_um')}; temperature_c "
              f"{_band(est, 'temperature_c', '{:.1f}')}")
    elif v == "sample":
        r = cp.sample(d, args.at_h, args.inputs, args.um_per_px, accept_unusable=args.accept_unusable,
                      scale_bar_um=args.scale_bar_um)
        for w in r.get("warnings", []):
            print(f"bmctl: warning: {w}", file=sys.stderr)
        print(f"sample {r['sample_id']} at {r['t_h']:g} h: {r['n']} particles, median s = {r['s_median_um']:.4g} µm, "
              f"median r = {r['r_median']:.3f}")
        if r["applied"]:
            est = r["estimate"]
            print(f"estimate at {est['t_h']:g} h ({r['replayed']} estimator step(s) recomputed):")
            print("\n".join(_estimate_lines(est)))
        else:
            print(f"held: the log reaches {r['clock_h']:g} h; the sample is used when it reaches {r['t_h']:g} h")
    elif v == "advise":
        model = cp.ensure_coefficients(d, identify=args.identify, progress=progress_printer())
        a = cp.advise(d, progress=progress_printer("advise"))
        warn_window(model, [r["rpm"] for r in a.get("schedule") or [] if r.get("mill_min", 1) > 0]
                    + ([a["next"]["rpm"]] if a.get("next") else []))
        print(json.dumps(a, indent=2) if args.json else "", end="\n" if args.json else "")
        if not args.json:
            _print_advice(a)
    elif v == "decide":
        r = cp.decide(d, args.accept, args.rpm, args.milling, args.note)
        what = "accepted" if r["accepted"] else "rejected"
        mm, ih = r.get("recommended_mill_min"), r.get("recommended_interval_h")
        minutes = "" if mm is None or ih is None else f": {mm:g} of {60 * ih:.4g} min"  # what the mill runs
        line = f"advice {r['plan_id']} at {r['t_h']:g} h {what} (recommended {r['recommended_rpm']:g} rpm, milling " \
               f"{r['recommended_milling']:.3g}{minutes})"
        instead = []
        if not r["accepted"] and r["rpm"] is not None:
            instead.append(f"{r['rpm']:g} rpm")
        if not r["accepted"] and r["milling"] is not None:
            instead.append(f"milling {r['milling']:g}")
        if instead:
            line += "; instead: " + ", ".join(instead)
        if r["replaces"]:
            line += f" (replaces {r['replaces']} earlier decision(s))"
        print(line + "; log what the mill then ran with `bmctl campaign log`")
    elif v == "status":
        s = cp.status(d)
        if args.json:
            print(json.dumps(s, indent=2))
            return 0
        n = s["counts"]
        print(f"campaign {d}: logged to {s['clock_h']:g} of {s['hours']:g} h; {n['actions']} actions, {n['samples']} "
              f"samples ({s['pending_samples']} waiting), {n['particles']} particles, {n['temperatures']} temperature "
              f"readings, {n['plans']} advices, {n['decisions']} decisions"
              + (f" ({s['decisions_replaced']} replaced by a later one)" if s["decisions_replaced"] else "")
              + f"; {s['db_bytes'] / 1e6:.2f} MB")
        print("target: " + ", ".join(f"{k} = {x:g}" for k, x in s["target"].items()))
        print(f"estimate at {s['estimate']['t_h']:g} h:" if s["estimate"]["t_h"] >= 0 else "estimate (prior):")
        print("\n".join(_estimate_lines(s["estimate"])))
        la = s["latest_advice"]
        if la:
            dec = s["decision"]
            what = ("batch finished" if la["interval_h"] <= 0 else f"rest {la['rest_min']:.0f} min"
                    if la["mill_min"] == 0 else f"{la['rpm']:g} rpm, mill {la['mill_min']:.0f} min, "
                    f"rest {la['rest_min']:.0f} min")
            print(f"latest advice at {la['t_h']:g} h: {what}"
                  + ("" if la["current"] else " (superseded by the log)")
                  + ("; no decision" if dec is None else f"; {'accepted' if dec['accepted'] else 'rejected'}"))
        for dv in s["deviations"]:
            print(dv)
        for w in s["warnings"]:
            print(f"warning: {w}")
    elif v == "report":
        p = cp.report(d, args.out)
        print(f"report: wrote {p}")
    return 0
