"""The campaign report: one self-contained HTML page, figures embedded as base64 PNG.

Figures: the estimate and its 90 % band against the target over time (with the measured
sample statistics), the measured size histograms against the model's law at the estimate,
the actions taken and recommended, the vial temperature (readings and estimate); then a
table of the samples and of the log. No scripts, no external resources.
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
from . import targets as tg


def _legend(ax) -> None:
    """A legend when the axes has labelled artists (an empty campaign has none: no warning then)."""
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7)


def _png(fig) -> str:
    buf = _io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _lognormal_pdf(s, mean, std):
    """Number-weighted log-normal density of s with the given mean and std (the law's shape
    for the figure; the filter's likelihood uses its own size law)."""
    sig2 = math.log1p((std / mean) ** 2)
    mu = math.log(mean) - sig2 / 2
    return np.exp(-(np.log(s) - mu) ** 2 / (2 * sig2)) / (s * math.sqrt(2 * math.pi * sig2))


def figures(c) -> dict[str, str]:
    """The report's figures as base64 PNG strings, by name."""
    plt = io.pyplot()
    est = c.estimates()
    t = np.array([e[0] for e in est])
    meta = c.meta
    target = meta["target"]
    out = {}
    samples = c.con.execute("SELECT id, t_h, n, s_median_um, r_median FROM samples ORDER BY t_h, id").fetchall()

    # 1. estimate and band against the target
    keys = ["s_mean_um", "s_std_um", "r_mean", "d50_um"]
    fig, axes = plt.subplots(1, 4, figsize=(15, 3.6))
    for ax, k in zip(axes, keys):
        if t.size:
            if k == "d50_um":
                v = np.array([tg.value_of(k, e[1]) for e in est])
                ax.plot(t, v, "C0-o", ms=3, label="estimate (at the mean moments)")
            else:
                ax.plot(t, [e[1][k] for e in est], "C0-o", ms=3, label="estimate")
                ax.fill_between(t, [e[1][f"{k}_q05"] for e in est], [e[1][f"{k}_q95"] for e in est], color="C0",
                                alpha=0.25, label="90 % band")
        if k in target:
            ax.axhline(target[k], color="C3", ls="--", label="target")
        if k == "s_mean_um" and samples:
            ax.plot([s[1] for s in samples], [s[3] for s in samples], "kx", label="sample median")
        unit = " (µm)" if k.endswith("_um") else ""
        ax.set_title(k.replace("_um", "") + unit), ax.set_xlabel("t (h)"), ax.grid(alpha=0.3)
        ax.set_xlim(0, meta["hours"])
    _legend(axes[0])
    fig.tight_layout()
    out["estimate"] = _png(fig)

    # 2. measured histograms against the model's law at the estimate of that time
    if samples:
        show = samples[-6:]
        fig, axes = plt.subplots(1, len(show), figsize=(3.2 * len(show), 3.0), squeeze=False)
        for ax, (sid, ts, n, _, _) in zip(axes[0], show):
            s, _ = c.particles(sid)
            e = min(est, key=lambda x: abs(x[0] - ts))[1] if est else None
            bins = np.geomspace(max(s.min() * 0.8, 1e-3), s.max() * 1.25, 25)
            ax.hist(s, bins=bins, density=True, color="C7", alpha=0.6, label=f"measured (n={n})")
            if e is not None:
                g = np.geomspace(bins[0], bins[-1], 200)
                ax.plot(g, _lognormal_pdf(g, e["s_mean_um"], e["s_std_um"]), "C0-", label="model at the estimate")
            ax.set_xscale("log"), ax.set_title(f"sample {sid} at {ts:g} h"), ax.set_xlabel("s (µm)")
        _legend(axes[0][0])
        fig.tight_layout()
        out["histograms"] = _png(fig)

    # 3. actions taken and recommended; 4. temperature
    acts = c.actions()
    plans = c.con.execute("SELECT t_h, rpm, milling, interval_h FROM plans ORDER BY id").fetchall()
    temps = c.con.execute("SELECT t_h, temperature_c FROM temperatures ORDER BY t_h").fetchall()
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(15, 3.6))
    for a in acts:
        ax.fill_between([a.t0_h, a.t0_h + a.milling * a.hours], 0, a.rpm, color="C2", alpha=0.5, step="pre", lw=0)
    if acts:
        ax.plot([], [], color="C2", lw=6, alpha=0.5, label="milled (logged)")
    if plans:
        ax.plot([p[0] + p[2] * p[3] / 2 for p in plans], [p[1] for p in plans], "C3v", label="recommended rpm")
    ax.set_xlim(0, meta["hours"]), ax.set_xlabel("t (h)"), ax.set_ylabel("rpm"), ax.grid(alpha=0.3)
    ax.set_title("actions: milled intervals (gaps are rests) and recommendations"), _legend(ax)
    if t.size:
        ax2.plot(t, [e[1]["temperature_c"] for e in est], "C0-", label="estimate")
        ax2.fill_between(t, [e[1]["temperature_c_q05"] for e in est], [e[1]["temperature_c_q95"] for e in est],
                         color="C0", alpha=0.25, label="90 % band")
    if temps:
        ax2.plot([x[0] for x in temps], [x[1] for x in temps], "C3o", label="reading")
    if meta.get("temperature_max_c") is not None:
        ax2.axhline(meta["temperature_max_c"], color="k", ls=":", label="ceiling")
    ax2.set_xlim(0, meta["hours"]), ax2.set_xlabel("t (h)"), ax2.set_title("vial temperature (°C)")
    ax2.grid(alpha=0.3), _legend(ax2)
    fig.tight_layout()
    out["actions"] = _png(fig)
    return out


def html_page(c) -> str:
    """The report page (a string). Every value from the database is escaped when the page is
    rendered (:func:`bmctl.htmlsafe.render`): the template is the only markup."""
    meta = c.meta
    figs = figures(c)
    samples = c.con.execute("SELECT id, t_h, n, s_median_um, r_median, sources FROM samples ORDER BY t_h, id").fetchall()
    srows = [(sid, f"{t:g}", n, f"{s:.4g}", f"{r:.3f}", ", ".join(Path(str(x)).name for x in json.loads(src)))
             for sid, t, n, s, r, src in samples]
    arows = [(f"{a.t0_h:g}", f"{a.t1_h:g}", f"{a.rpm:g}", f"{a.milling * a.hours * 60:.0f}",
              f"{(1 - a.milling) * a.hours * 60:.0f}", dev)
             for a, dev in zip(c.actions(), [r[0] for r in c.con.execute("SELECT deviation FROM actions ORDER BY t0_h")])]
    plan = c.latest_plan()
    advice = hs.Markup("")
    if plan is not None:
        a = json.loads(plan[5])
        nx = a["next"]
        reach = "; ".join(f"{k} {'reachable' if ok else 'not reachable'}" for k, ok in a["reachable"].items())
        advice = hs.render("<p>Latest advice at {t} h: <b>{rpm} rpm, mill {mill} min, rest {rest} min</b>; "
                           "binding: {binding}; {reach}</p>", t=a["t_h"], rpm=nx["rpm"], mill=nx["mill_min"],
                           rest=nx["rest_min"], binding="; ".join(map(str, a["binding"])) or "none", reach=reach)
    tgt = ", ".join(f"{k} = {v:g}" for k, v in meta["target"].items())
    img = lambda k, alt: hs.render('<figure><img alt="{alt}" src="data:image/png;base64,{data}"><figcaption>{alt}'  # noqa: E731
                                   "</figcaption></figure>", alt=alt, data=figs[k]) if k in figs else ""
    return hs.render("""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>bmctl campaign report</title>
<style>body{{font-family:sans-serif;margin:1.5em;max-width:1400px}} img{{max-width:100%}}
table{{border-collapse:collapse;font-size:0.9em}} td,th{{border:1px solid #bbb;padding:2px 8px;text-align:right}}</style>
</head><body>
<h1>Campaign report</h1>
<p>{hours:g} h batch; target {tgt}; controller {kind};
card {card}; logged to {clock:g} h.</p>
{advice}
{fig1}
{fig2}
{fig3}
<h2>Samples</h2>
{samples}
<h2>Log</h2>
{log}
</body></html>
""", hours=meta["hours"], tgt=tgt, kind=meta["controller_kind"], card=Path(meta["inputs"]["card"]["file"]).name,
        clock=c.clock_h(), advice=advice,
        fig1=img("estimate", "Estimate and its 90 % band against the target over time"),
        fig2=img("histograms", "Measured size histograms against the model law at the estimate"),
        fig3=img("actions", "Actions taken and recommended; vial temperature"),
        samples=hs.table(["id", "t (h)", "particles", "median s (µm)", "median r", "sources"], srows),
        log=hs.table(["from (h)", "to (h)", "rpm", "milling (min)", "rest (min)", "deviation"], arows))


def write_report(c, path: Path) -> Path:
    """Write the report atomically; returns ``path``."""
    io.write_text(path, html_page(c))
    return path
