"""The campaign report: one self-contained HTML page an engineer files with the batch.

What it holds, in order:

1. the batch (card, controller, target, ceiling, logged time), every temperature warning and
   every sample update that left the filter nearly degenerate;
2. per sample, the estimate at its time with the 90 % interval next to the sample's own
   statistic of the *same* quantity (number mean and std of s, the std with n - 1, mean of r,
   volume-weighted D50 by :func:`bmctl.stats.dvalues`), and the target; as a figure over time and
   as a table;
3. the measured size histograms against the filter's size law at the estimate;
4. every advice: the estimate it saw, the recommended interval, reachability, binding
   constraints, the sample asked for first, warnings, the decision (accepted / rejected, what instead,
   the note; or the one recorded on an earlier advice at the same time that it repeats,
   :func:`bmctl.campaign.workflow.standing_decision`), what was then logged and the deviation,
   and the plan to the batch end that was advised (a table per advice, and all plans in one figure);
5. the vial-temperature readings against the ceiling, with the estimate and each reading's check;
6. the log as recorded.

The page is built with :mod:`bmctl.htmlsafe` (trusted templates, every value escaped at
render). Figures are base64 PNG; no scripts, no external resources.
"""

from __future__ import annotations

import base64
import io as _io
import json
import math
from pathlib import Path

import numpy as np

from .. import htmlsafe as hs
from .. import io
from .readings import estimate_warning, interval_text, reading_warnings

#: the estimate's quantities shown against the samples: key -> (title, the sample statistic of it)
QUANTITIES = {
    "s_mean_um": ("mean size s (µm), number-weighted", "sample mean"),
    "s_std_um": ("std of s (µm), number-weighted", "sample std"),
    "r_mean": ("mean irregularity r", "sample mean"),
    "d50_um": ("D50 (µm), volume-weighted", "sample D50"),
}
#: delta degrees of freedom of a sample's standard deviation (n - 1: the unbiased variance)
SAMPLE_DDOF = 1


def sample_statistics(s_um: np.ndarray, r: np.ndarray) -> dict[str, float]:
    """A sample's own statistics of the estimate's quantities (:data:`QUANTITIES`).

    Parameters
    ----------
    s_um, r : ndarray
        Sizes (µm) and irregularities of the sample's particles.

    Returns
    -------
    dict
        ``s_mean_um, s_std_um`` (number-weighted), ``r_mean``, ``r_std`` and ``d50_um``
        (volume-weighted, :func:`bmctl.stats.dvalues`). The standard deviations are the sample's,
        with n - 1 (``ddof=1``, as :func:`bmctl.campaign.advice.sampling` reads the spread); NaN
        for a sample of one particle, which shows no spread.

    Examples
    --------
    >>> st = sample_statistics(np.array([10.0, 20.0, 30.0]), np.array([0.1, 0.2, 0.3]))
    >>> round(st["s_mean_um"], 6), round(st["s_std_um"], 6), round(st["r_mean"], 6)
    (20.0, 10.0, 0.2)
    >>> sample_statistics(np.array([10.0]), np.array([0.1]))["s_std_um"]
    nan
    """
    from ..stats import dvalues

    s_um, r = np.asarray(s_um, dtype=float), np.asarray(r, dtype=float)

    def std(v: np.ndarray) -> float:
        return float(v.std(ddof=SAMPLE_DDOF)) if v.size > SAMPLE_DDOF else math.nan

    return {"s_mean_um": float(s_um.mean()), "s_std_um": std(s_um), "r_mean": float(r.mean()),
            "r_std": std(r), "d50_um": float(dvalues(s_um)["d50_um"])}


def _png(fig) -> str:
    buf = _io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _law_pdf(s, mean, std):
    """Number-weighted density of s under the filter's size law (Weibull of that mean and std,
    :func:`bmctl.stats.weibull_params`), per µm."""
    from ..stats import weibull_params

    k, lam = weibull_params(float(mean), float(std))
    u = np.asarray(s, dtype=float) / lam
    return k / lam * u ** (k - 1) * np.exp(-u**k)


class ReportData:
    """Everything the page shows, read once from the campaign (inside its read transaction)."""

    def __init__(self, c):
        self.meta = c.meta
        self.clock_h = c.clock_h()
        self.ceiling_c = c.ceiling_c()
        self.sigma_reading_c = c.filter_settings().sigma_temperature_c
        self.ambient_c = c.ambient_c()
        self.nodes = c.estimates()
        _, self.now_t, self.now = c.last_node()  # the estimate now: the prior (t < 0) before anything is logged
        self.prior = c.prior_estimate()  # the card's starting powder: batch time 0
        self.rpm_max = c.rpm_max()
        self.filter_warnings = c.band_warnings()  # sample updates that left the filter nearly degenerate
        self.actions = c.actions()
        self.deviations = {r[0]: r[1] for r in c.con.execute("SELECT id, deviation FROM actions")}
        self.temps = c.con.execute("SELECT t_h, temperature_c FROM temperatures ORDER BY t_h, id").fetchall()
        self.samples = []
        for sid, t, n, src in c.con.execute("SELECT id, t_h, n, sources FROM samples ORDER BY t_h, id").fetchall():
            s, r = c.particles(sid)
            self.samples.append({"id": sid, "t_h": float(t), "n": int(n), "s_um": s, "r": r,
                                 "sources": [Path(x).name for x in json.loads(src)], "stats": sample_statistics(s, r),
                                 "estimate": self.node_at(float(t))})
        from .workflow import repeats, standing_decision

        self.plans = []
        rows = c.con.execute("SELECT id, t_h, advice FROM plans ORDER BY id").fetchall()
        for i, (pid, t, advice) in enumerate(rows):
            dec = c.con.execute("SELECT accepted, rpm, milling, note FROM decisions WHERE plan_id = ? ORDER BY id",
                                (pid,)).fetchall()
            act = c.con.execute("SELECT id FROM actions WHERE plan_id = ? ORDER BY t0_h", (pid,)).fetchall()
            advice = json.loads(advice)
            # the advice asked for again at the same logged time (the log links what was run to the latest)
            later = next((r for r in rows[i + 1:] if abs(float(r[1]) - float(t)) < 1e-6), None)
            again = None if later is None else (later[0], repeats(json.loads(later[2])["next"], advice["next"]))
            self.plans.append({"id": pid, "t_h": float(t), "advice": advice, "decisions": dec,
                               "standing": None if dec else standing_decision(c.con, pid), "again": again,
                               "actions": [a[0] for a in act]})

    def node_at(self, t_h: float) -> dict | None:
        """The estimate of the timeline node at ``t_h`` (None when the log has not reached it)."""
        hits = [e for t, e in self.nodes if abs(t - t_h) < 1e-6]
        return hits[-1] if hits else None

    def warnings(self) -> list[str]:
        out = []
        for _, est in self.nodes:
            out += reading_warnings(est, self.ceiling_c, self.sigma_reading_c, self.ambient_c)
        if self.nodes:
            out += estimate_warning(self.nodes[-1][1], self.ceiling_c)
        return out + self.filter_warnings


# --- figures ----------------------------------------------------------------------------------------
#: the estimate figure's y axis of each quantity (:data:`QUANTITIES` titles them)
YLABELS = {"s_mean_um": "s (µm)", "s_std_um": "std of s (µm)", "r_mean": "r", "d50_um": "D50 (µm)"}
#: what the page calls the card's prior, drawn at batch time 0
PRIOR_LABEL = "prior at 0 h (the card's powder)"
#: share of the batch added each side of a time axis, so that markers at 0 h and at the batch end show whole
TIME_MARGIN = 0.02
#: the estimate's markers are drawn above the readings, the samples and the prior, and smaller than
#: they are (those hollow), so that where an estimate and a reading nearly coincide both show
ESTIMATE_Z, MEASURED_Z = 4, 3


def _time_axis(ax, hours: float, times=()) -> None:
    """Batch time from 0 to the batch end (or the latest time drawn, if later), with a small margin."""
    hi = max([float(hours)] + [float(x) for x in times])
    hi = hi if hi > 0 else 1.0
    ax.set_xlim(-TIME_MARGIN * hi, (1 + TIME_MARGIN) * hi)
    ax.set_xlabel("batch time (h)")


def _note(ax, text: str) -> None:
    """Say in the axes what is not there to draw."""
    ax.text(0.5, 0.5, text, transform=ax.transAxes, ha="center", va="center", fontsize=9, color="0.35",
            bbox={"facecolor": "white", "edgecolor": "0.8", "alpha": 0.9})


def _over_time(ax, nodes: list[tuple[float, dict]], k: str, prior: bool) -> None:
    """Mean and 90 % interval of estimate ``k`` at the nodes (the card's prior at 0 h first when
    ``prior``): a band where the nodes span some time, error bars where the logged nodes stand at one
    time (a band over one time has no width; from the prior to one node it is a thin wedge), and the
    prior marked at 0 h."""
    t = np.array([x[0] for x in nodes], dtype=float)
    m = np.array([e[k] for _, e in nodes], dtype=float)
    lo = np.array([e[f"{k}_q05"] for _, e in nodes], dtype=float)
    hi = np.array([e[f"{k}_q95"] for _, e in nodes], dtype=float)
    only_prior = prior and t.size == 1
    if np.unique(t).size > 1:
        ax.fill_between(t, lo, hi, color="C0", alpha=0.25, lw=0, label="estimate, 90 % interval")
        ax.plot(t, m, "C0-o", ms=3, zorder=ESTIMATE_Z, label="estimate (mean)")
        i = 1 if prior else 0  # the logged nodes
        if np.unique(t[i:]).size == 1:  # all at one time: the band is a thin wedge from the prior, so bars too
            ax.errorbar(t[i:], m[i:], yerr=np.clip([m[i:] - lo[i:], hi[i:] - m[i:]], 0.0, None), fmt="none",
                        ecolor="C0", capsize=4, lw=1.2, zorder=ESTIMATE_Z)
    else:
        err = np.clip([m - lo, hi - m], 0.0, None)  # a mean on a zero-width interval: no negative bar
        if only_prior:
            ax.errorbar(t, m, yerr=err, fmt="s", color="C0", mfc="none", ms=6, mew=1.3, capsize=4, lw=1.2,
                        zorder=MEASURED_Z, label=f"{PRIOR_LABEL}, mean and 90 % interval")
            return
        ax.errorbar(t, m, yerr=err, fmt="o", color="C0", ms=4, capsize=4, lw=1.2, zorder=ESTIMATE_Z,
                    label="estimate, mean and 90 % interval")
    if prior:  # hollow and under the estimate: an estimate at 0 h (a sample of the feed) shows inside it
        ax.plot(t[:1], m[:1], "s", color="C0", mfc="none", ms=6, mew=1.3, zorder=MEASURED_Z, label=PRIOR_LABEL)


def _fig_legend(fig, axes, ncol: int | None = None) -> None:
    """One legend for the figure, outside the axes (below them), each label once; none without labels."""
    seen: dict[str, object] = {}
    for ax in axes:
        kids = ax.get_children()

        def drawn_at(pair, kids=kids) -> int:  # in the order drawn (matplotlib lists error bars last)
            h = pair[0]
            a = h[0] if isinstance(h, tuple) and len(h) and h[0] is not None else h
            return next((i for i, x in enumerate(kids) if x is a), len(kids))

        for h, lab in sorted(zip(*ax.get_legend_handles_labels()), key=drawn_at):
            seen.setdefault(lab, h)
    if seen:
        fig.legend(list(seen.values()), list(seen), loc="outside lower center", fontsize=8,
                   ncol=ncol or min(len(seen), 4), frameon=False)


def figures(d: ReportData) -> dict[str, str]:
    """The report's figures as base64 PNG strings, by name."""
    plt = io.pyplot()
    from ..plots import log_size_axis

    out = {}
    H = d.meta["hours"]
    prior = d.prior is not None
    nodes = ([(0.0, d.prior)] if prior else []) + list(d.nodes)  # the prior is the estimate at batch time 0
    times = [x[0] for x in nodes] + [s["t_h"] for s in d.samples] + [a.t1_h for a in d.actions]
    target = d.meta["target"]

    # 1. estimate and band of each quantity; each sample's statistic of the same quantity; the target
    fig, axes = plt.subplots(2, 2, figsize=(11, 7.0), layout="constrained")
    for ax, (k, (title, stat)) in zip(axes.flat, QUANTITIES.items()):
        if nodes:
            _over_time(ax, nodes, k, prior)
        if d.samples:
            ax.plot([s["t_h"] for s in d.samples], [s["stats"][k] for s in d.samples], "kx", ms=8, mew=1.5,
                    zorder=MEASURED_Z, label="sample statistic (mean, std or D50, as titled)")
        if k in target:
            ax.axhline(target[k], color="C3", ls="--", label="target")
        if not d.nodes and not d.samples:
            _note(ax, "nothing logged yet" + (": the card's prior at 0 h" if prior else ""))
        ax.set_title(title, fontsize=10), ax.set_ylabel(YLABELS.get(k, k)), ax.grid(alpha=0.3)
        _time_axis(ax, H, times)
    _fig_legend(fig, axes.flat)
    out["estimate"] = _png(fig)

    # 2. measured histograms against the filter's size law at the estimate of that time
    shown = [s for s in d.samples if s["estimate"] is not None][-6:]
    if shown:
        ncol = min(3, len(shown))
        nrow = math.ceil(len(shown) / ncol)
        fig, axes = plt.subplots(nrow, ncol, figsize=(3.8 * ncol, 3.0 * nrow + 0.4), squeeze=False,
                                 layout="constrained")
        for ax, s in zip(axes.flat, shown):
            x = s["s_um"]
            bins = np.geomspace(max(x.min() * 0.8, 1e-3), x.max() * 1.25, 25)
            g = np.geomspace(bins[0], bins[-1], 200)
            # density per unit ln s (s f(s)) on a log axis: the shape is not flattened by the axis
            w = np.full(x.size, 1.0 / (x.size * np.log(bins[1] / bins[0])))
            ax.hist(x, bins=bins, weights=w, color="C7", alpha=0.6, label="measured")
            e = s["estimate"]
            ax.plot(g, g * _law_pdf(g, e["s_mean_um"], e["s_std_um"]), "C0-", label="size law at the estimate")
            ax.set_xscale("log"), log_size_axis(ax)
            ax.set_title(f"sample {s['id']} at {s['t_h']:g} h (n = {s['n']})", fontsize=10)
            ax.set_xlabel("s (µm)"), ax.set_ylabel("density per ln s")
        for ax in list(axes.flat)[len(shown):]:
            ax.set_visible(False)
        _fig_legend(fig, axes.flat[:1])
        out["histograms"] = _png(fig)

    # 3. what was run, what was advised (the next interval and the whole plan at each advice)
    fig, ax = plt.subplots(figsize=(11, 3.4), layout="constrained")
    for a in d.actions:
        if a.milling > 0 and a.rpm > 0:
            ax.fill_between([a.t0_h, a.t0_h + a.milling * a.hours], 0, a.rpm, color="C2", alpha=0.5, lw=0)
    if d.actions:
        ax.plot([], [], color="C2", lw=6, alpha=0.5, label="milled (logged; gaps are rests)")
    cmap = plt.get_cmap("viridis")
    plan_times: list[float] = []
    drawn_rpm = [float(a.rpm) for a in d.actions if a.milling > 0 and a.rpm > 0]
    for i, p in enumerate(d.plans):
        rows = p["advice"].get("schedule", [])
        if not rows:
            continue
        col = cmap(i / max(len(d.plans) - 1, 1))
        ts = [r["t0_h"] for r in rows] + [rows[-1]["t1_h"]]
        rpm = [r["rpm"] if r["mill_min"] > 0 else 0.0 for r in rows]
        first = not plan_times  # the first plan drawn names the series
        ax.step(ts, rpm + rpm[-1:], where="post", color=col, lw=1, alpha=0.7,
                label="plan at each advice (early → late)" if first else None)
        nx = p["advice"]["next"]
        ax.plot([p["t_h"]], [nx["rpm"]], "v", color="C3", ms=7, label="recommended next" if first else None)
        plan_times += ts + [p["t_h"]]
        drawn_rpm += [float(x) for x in rpm] + [float(nx["rpm"])]
    # from 0 (a rest), also where only plans are drawn: a plan at one speed made an axis of 285-315 rpm
    top = max(drawn_rpm, default=0.0)
    ax.set_ylim(0, 1.05 * (top if top > 0 else d.rpm_max))
    if not d.actions and not plan_times:
        _note(ax, "nothing logged or advised yet")
    _time_axis(ax, H, times + plan_times)
    ax.set_ylabel("rpm"), ax.grid(alpha=0.3)
    ax.set_title("mill: logged intervals, recommendations and the plan advised at each step", fontsize=10)
    _fig_legend(fig, [ax])
    out["actions"] = _png(fig)

    # 4. vial temperature: readings against the ceiling, the estimate and its interval
    fig, ax = plt.subplots(figsize=(11, 3.8), layout="constrained")
    if nodes:
        _over_time(ax, nodes, "temperature_c", prior)
    if d.temps:
        ty = np.array(d.temps, dtype=float)
        over = ty[:, 1] > (d.ceiling_c if d.ceiling_c is not None else np.inf)
        if (~over).any():
            ax.plot(ty[~over, 0], ty[~over, 1], "o", color="C1", mfc="none", ms=8, mew=1.5, zorder=MEASURED_Z,
                    label="reading")
        if over.any():
            ax.plot(ty[over, 0], ty[over, 1], "X", color="C3", mfc="none", ms=9, mew=1.5, zorder=MEASURED_Z,
                    label="reading above the ceiling")
    else:
        _note(ax, "no reading logged yet" if d.nodes else "nothing logged yet")
    if d.ceiling_c is not None:
        ax.axhline(d.ceiling_c, color="k", ls=":", label=f"ceiling {d.ceiling_c:g} °C")
    _time_axis(ax, H, times)
    ax.set_ylabel("vial temperature (°C)"), ax.grid(alpha=0.3)
    ax.set_title(f"vial temperature: readings (σ {d.sigma_reading_c:g} °C) against the ceiling", fontsize=10)
    _fig_legend(fig, [ax])
    out["temperature"] = _png(fig)
    return out


# --- page -----------------------------------------------------------------------------------------
def _band(est: dict | None, k: str, fmt: str = "{:.4g}") -> str:
    """``mean  [q05, q95]`` of an estimate dict, as ``bmctl campaign status`` prints it."""
    if est is None or k not in est:
        return "n/a"
    return f"{fmt.format(est[k])}  [{fmt.format(est[f'{k}_q05'])}, {fmt.format(est[f'{k}_q95'])}]"


def _samples_table(d: ReportData) -> hs.Markup:
    header = ["sample", "t (h)", "particles"]
    for k, (title, stat) in QUANTITIES.items():
        header += [f"{k}: estimate [90 %]", f"{k}: {stat}"]
    header += ["sources"]
    rows = []
    for s in d.samples:
        row = [s["id"], f"{s['t_h']:g}", s["n"]]
        for k in QUANTITIES:
            v = s["stats"][k]
            row += [_band(s["estimate"], k) if s["estimate"] else "waits for the log",
                    f"{v:.4g}" if math.isfinite(v) else f"n/a ({s['n']} particle)"]
        rows.append(row + [", ".join(s["sources"])])
    return hs.table(header, rows)


def _why(a: dict) -> str:
    """The advice's ``why`` lines (:func:`bmctl.campaign.advice.reach_line`); a target or end band
    that is not plain numbers is shown as the bare verdict."""
    from .advice import cooling_now, reach_line

    def num(x) -> bool:
        return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)

    out = []
    for k, ok in a.get("reachable", {}).items():
        v, e = a.get("target", {}).get(k), a.get("end", {}).get(k)
        if num(v) and isinstance(e, dict) and all(num(e.get(q)) for q in ("median", "q05", "q95")):
            out.append(reach_line(str(k), float(v), e, bool(ok), cooling_now(a.get("binding"))))
        else:
            out.append(f"{k} {'reachable' if ok else 'NOT reachable'}")
    return "; ".join(out)


def _decision_text(accepted, rpm, milling) -> str:
    """A decision as the report words it: accepted, or rejected and what instead."""
    text = "accepted" if accepted else "rejected"
    if not accepted and rpm is not None:
        text += f"; instead {rpm:g} rpm"
    if not accepted and milling is not None:
        text += f", milling {milling:g}"
    return text


def _advice_section(d: ReportData) -> hs.Markup:
    acts = {a.id: a for a in d.actions}
    parts = []
    for p in d.plans:
        a = p["advice"]
        nx = a["next"]
        rec = ("batch finished" if nx["interval_h"] <= 0 else
               f"{nx['rpm']:g} rpm, mill {nx['mill_min']} min, rest {nx['rest_min']} min")
        if p["decisions"]:
            acc, rpm, mil, note = p["decisions"][-1]
            dec = _decision_text(acc, rpm, mil)
            if len(p["decisions"]) > 1:
                dec += f" (replaces {len(p['decisions']) - 1} earlier decision(s))"
        elif p["standing"]:  # recorded on an earlier advice at this time that this one repeats
            acc, rpm, mil, note, src = p["standing"]
            dec = _decision_text(acc, rpm, mil) + f" (recorded on advice {src}, which this advice repeats)"
        else:
            dec, note = "no decision recorded", ""
        ran = []
        for aid in p["actions"]:
            x = acts.get(aid)
            if x is None:
                continue
            ran.append(f"{x.t0_h:g}-{x.t1_h:g} h: " + interval_text(x.rpm, x.milling, x.hours))
        dev = "; ".join(d.deviations.get(aid, "") for aid in p["actions"] if d.deviations.get(aid)) or "none"
        if not ran and p["again"]:  # what was run is under the later advice at this time
            later, same = p["again"]
            ran = [f"nothing under this advice: advice {later} at this time {'repeats' if same else 'replaces'} it"]
            dev = f"see advice {later}"
        est = a["estimate"]
        reach = _why(a)
        items = [("recommended next", rec),
                 ("estimate seen", "; ".join(f"{k} {_band(est, k)}" for k in ("s_mean_um", "d50_um", "temperature_c")
                                             if k in est)),
                 ("target", ", ".join(f"{k} = {v:g}" for k, v in a["target"].items())),
                 ("why", reach or "n/a"),
                 ("binding", "; ".join(map(str, a.get("binding", []))) or "no constraint binds"),
                 ("sample first", a.get("sample_first") or "not asked"),
                 ("warnings", "; ".join(map(str, a.get("warnings", []))) or "none"),
                 ("notes", "; ".join(map(str, a.get("notes", []))) or "none"),
                 ("solver", a.get("solver", "")),
                 ("decision", dec), ("note", note or "none"),
                 ("then logged", "; ".join(ran) or "nothing yet"), ("deviation", dev)]
        dl = hs.join(hs.render("<dt>{k}</dt><dd>{v}</dd>", k=k, v=v) for k, v in items)
        sched = [(f"{r['t0_h']:.2f}-{r['t1_h']:.2f}", f"{r['rpm']:.0f}", r["mill_min"], r["rest_min"],
                  "" if r["planned"] else "held") for r in a.get("schedule", [])]
        end = [(k, f"{e['median']:.4g}", f"[{e['q05']:.4g}, {e['q95']:.4g}]") for k, e in a.get("end", {}).items()]
        parts.append(hs.render(
            '<section class="advice" id="advice-{pid}"><h3>Advice {pid} at {t:g} h</h3><dl>{dl}</dl>'
            "<details><summary>plan advised to the batch end ({n} intervals) and the predicted end state</summary>"
            '<div class="plan">{plan}</div><div class="end">{end}</div></details></section>',
            pid=p["id"], t=p["t_h"], dl=dl, n=len(sched),
            plan=hs.table(["interval (h)", "rpm", "mill (min)", "rest (min)", ""], sched),
            end=hs.table(["at the batch end", "median", "90 % band"], end)))
    return hs.join(parts) if parts else hs.Markup("<p>No advice was asked for.</p>")


def _temperature_table(d: ReportData) -> hs.Markup:
    rows = []
    for t, y in d.temps:
        e = d.node_at(float(t))
        checks = reading_warnings(e, d.ceiling_c, d.sigma_reading_c, d.ambient_c) if e else []
        rows.append((f"{t:g}", f"{y:g}", "n/a" if d.ceiling_c is None else ("ABOVE" if y > d.ceiling_c else "below"),
                     "n/a" if e is None or "reading_predicted_c" not in e else
                     f"{e['reading_predicted_c']:.1f} ± {e['reading_predicted_sd_c']:.1f}",
                     _band(e, "temperature_c", "{:.1f}"), "; ".join(checks) or "none"))
    return hs.table(["t (h)", "reading (°C)", "vs ceiling", "estimate before (°C)", "estimate after (°C) [90 %]",
                     "warnings"], rows)


PAGE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>bmctl campaign report</title>
<style>body{{font-family:sans-serif;margin:1.5em;max-width:1400px}} img{{max-width:100%}}
table{{border-collapse:collapse;font-size:0.9em;margin:0.4em 0}} td,th{{border:1px solid #bbb;padding:2px 8px;text-align:right}}
dl{{display:grid;grid-template-columns:max-content auto;gap:2px 12px}} dt{{font-weight:bold}} dd{{margin:0}}
.warnings li{{color:#a00}} section.advice{{border-top:1px solid #ccc;margin-top:1em}}</style>
</head><body>
<h1>Campaign report</h1>
<p>{hours:g} h batch; target {tgt}; vial-temperature ceiling {ceiling}; controller {kind}; card {card};
logged to {clock:g} h; {n_act} intervals, {n_smp} samples, {n_tmp} temperature readings, {n_adv} advices.</p>
<h2>Warnings</h2>
{warnings}
<h2>Estimate now</h2>
{estimate}
<h2>Samples: the estimate against each sample's statistic of the same quantity</h2>
<p>A sample's std is its standard deviation with n &minus; 1 (n its particles); a sample of one particle has none.</p>
{fig_estimate}
{samples}
{fig_hist}
<h2>Advice and decisions</h2>
{fig_actions}
{advice}
<h2>Vial temperature</h2>
{fig_temperature}
{temperatures}
<h2>Log</h2>
{log}
</body></html>
"""


def html_page(c) -> str:
    """The report page (a string). Every value is escaped when the page is rendered
    (:func:`bmctl.htmlsafe.render`): the templates in this module are the only markup."""
    d = ReportData(c)
    figs = figures(d)
    meta = d.meta
    temps = {round(t, 9): y for t, y in d.temps}
    arows = []
    for a in d.actions:
        mm = a.milling * a.hours * 60
        y = temps.get(round(a.t1_h, 9))
        arows.append((f"{a.t0_h:g}", f"{a.t1_h:g}", f"{a.rpm:g}" if mm > 0 else "0 (rest)", f"{mm:.0f}",
                      f"{a.hours * 60 - mm:.0f}", "" if y is None else f"{y:g}", d.deviations.get(a.id, "")))
    warns = d.warnings()
    wblock = (hs.render('<ul class="warnings">{items}</ul>', items=hs.join(hs.render("<li>{w}</li>", w=w)
                                                                           for w in warns))
              if warns else hs.Markup("<p>No warnings.</p>"))
    last = d.now  # as ``bmctl campaign status``: the prior, labelled, before anything is logged
    est_rows = [(k, _band(last, k)) for k in ("s_mean_um", "s_std_um", "r_mean", "r_std", "d50_um", "temperature_c",
                                              "thermal_gain", "gamma_mult", "delta_mult", "energy_mult") if last and k in last]
    est_when = ("prior: the card's starting powder (nothing logged yet)" if d.now_t < 0
                else f"at {d.now_t:g} h")

    def img(k: str, alt: str) -> hs.Markup:
        return hs.png_figure(base64.b64decode(figs[k]), alt) if k in figs else hs.Markup("")

    return hs.render(
        PAGE, hours=meta["hours"], tgt=", ".join(f"{k} = {v:g}" for k, v in meta["target"].items()),
        ceiling="none" if d.ceiling_c is None else f"{d.ceiling_c:g} °C", kind=meta["controller_kind"],
        card=Path(str(meta["inputs"]["card"]["file"])).name, clock=d.clock_h, n_act=len(d.actions),
        n_smp=len(d.samples), n_tmp=len(d.temps), n_adv=len(d.plans), warnings=wblock,
        estimate=hs.join([hs.render("<p>{w}</p>", w=est_when),
                          hs.table(["quantity", "mean [90 % interval]"], est_rows)]),
        fig_estimate=img("estimate", "Estimate (mean and 90 % interval) of each quantity over batch time, each "
                                     "sample statistic of the same quantity, and the target"),
        samples=_samples_table(d),
        fig_hist=img("histograms", "Measured size distributions against the filter size law at the estimate "
                                   "(density per ln s)"),
        fig_actions=img("actions", "Logged intervals, recommendations and the plan advised at each step"),
        advice=_advice_section(d),
        fig_temperature=img("temperature", "Vial-temperature readings against the ceiling, with the estimate"),
        temperatures=_temperature_table(d),
        log=hs.table(["from (h)", "to (h)", "rpm", "milling (min)", "rest (min)", "reading (°C)", "deviation"], arows))


def write_report(c, path: Path) -> Path:
    """Write the report atomically; returns ``path``."""
    page = html_page(c)  # a path stored before names were kept printable may hold bytes that are not UTF-8
    io.write_text(path, page.encode("utf-8", "backslashreplace").decode("utf-8"))
    return path
