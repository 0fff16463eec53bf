"""What the moment model's shape closure has to carry: the plant's size–shape link and round share.

On the lab card at its recipe speed (300 rpm), M = 20,000, seeds 0-3, after 1 h and after 12 h:
the mean aspect ratio r and the mean size of the five size quintiles, the share of the
variance of r that lies between the quintiles, the share of particles with r = 0 exactly and the
skewness of ln s. Also the lab model's contact-length nodes (``physics.CONTACT_BINS``: the
conditional means of sqrt(U_in / E[U_in]) in four equal-probability bins, a seeded Monte Carlo of
the card's impact energies). And the plant's own s–r link on every shipped card at its recipe
speed (after 1, 3, 6 and 12 h, seed 0) and on the fan card at rpm_max/3 and rpm_max (after 6 h):
the least-squares slope of logit E[r | s] on ln s over the size deciles (the quantity the
closure's β approximates). docs/moments.md (Secs. 2, 4, 6, 7) quotes them.

    python benchmarks/moments_plant_shape.py     # under a minute; writes results/moments_plant_shape.json
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bmctl.config import load_card  # noqa: E402
from bmctl.moments.model import make_moment_model  # noqa: E402
from bmctl.plant.plant import Plant  # noqa: E402

CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
COMMAND = "python benchmarks/moments_plant_shape.py"


def shape_facts(s: np.ndarray, r: np.ndarray) -> dict:
    s_um = 1e6 * s
    edges = np.quantile(s_um, np.linspace(0, 1, 6))
    q = np.clip(np.searchsorted(edges, s_um, side="right") - 1, 0, 4)
    means = np.array([r[q == k].mean() for k in range(5)])
    shares = np.array([np.mean(q == k) for k in range(5)])
    between = float(np.sum(shares * (means - r.mean()) ** 2) / r.var())
    ln = np.log(s_um)
    skew = float(np.mean((ln - ln.mean()) ** 3) / ln.std() ** 3)
    sizes = np.array([s_um[q == k].mean() for k in range(5)])
    return {"quintile_r_mean": means, "quintile_s_mean_um": sizes, "quintile_edges_um": edges, "between_pct": 100 * between,
            "round_pct": 100 * float(np.mean(r <= 0.0)), "ln_s_skewness": skew}


def link_slope(s: np.ndarray, r: np.ndarray) -> float:
    """Least-squares slope of logit(mean r) on mean ln s over the size deciles."""
    ln = np.log(s)
    edges = np.quantile(ln, np.linspace(0, 1, 11))
    q = np.clip(np.searchsorted(edges, ln, side="right") - 1, 0, 9)
    x = np.array([ln[q == k].mean() for k in range(10)])
    m = np.array([r[q == k].mean() for k in range(10)])
    ok = (m > 0) & (m < 1)
    return float(np.polyfit(x[ok], np.log(m[ok] / (1 - m[ok])), 1)[0])


def plant_link(card, rpm: float, times, particles: int, seed: int = 0) -> list[float]:
    plant = Plant(card, np.random.default_rng(seed), particles)
    out, t = [], 0.0
    for t_h in times:
        plant.advance(rpm, t_h - t)
        t = t_h
        out.append(link_slope(plant.s, plant.r))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--particles", type=int, default=20000)
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--no-results", action="store_true")
    a = ap.parse_args(argv)
    card = load_card(CARD)
    rpm = card.process.rpm
    out = {}
    for hours in (1.0, 12.0):
        per_seed = []
        for seed in range(a.seeds):
            plant = Plant(card, np.random.default_rng(seed), a.particles)
            plant.advance(rpm, hours)
            per_seed.append(shape_facts(plant.s, plant.r))
        avg = {k: np.mean([f[k] for f in per_seed], axis=0) for k in per_seed[0]}
        rng_ = {f"{k}_min": float(min(f[k] for f in per_seed)) for k in ("round_pct", "ln_s_skewness")}
        rng_.update({f"{k}_max": float(max(f[k] for f in per_seed)) for k in ("round_pct", "ln_s_skewness")})
        out[f"h{hours:g}"] = {**avg, **rng_}
        f = out[f"h{hours:g}"]
        print(f"{hours:g} h at {rpm:g} rpm: quintile r means " + ", ".join(f"{v:.3f}" for v in f["quintile_r_mean"])
              + " (mean sizes " + ", ".join(f"{v:.0f}" for v in f["quintile_s_mean_um"]) + " um); between-quintile share of "
              f"var r {f['between_pct']:.0f} %; r = 0: {f['round_pct']:.0f} %; skewness of ln s {f['ln_s_skewness']:.2f}")
    model = make_moment_model(CARD)
    nodes = [f for _, f in model.const.contact_nodes]
    out["contact_nodes"] = nodes
    print("contact-length nodes (lab model): " + ", ".join(f"{v:.2f}" for v in nodes))
    links = {}
    for path in sorted((ROOT / "models").glob("*.moments.toml")):
        c = load_card(path.with_name(path.name.removesuffix(".moments.toml") + ".toml"))
        sl = plant_link(c, c.process.rpm, (1.0, 3.0, 6.0, 12.0), a.particles)
        links[c.card.name] = {"rpm": c.process.rpm, "slopes": sl, "min": min(sl), "max": max(sl)}
        print(f"{c.card.name} at {c.process.rpm:g} rpm: plant logit slope of E[r | s] on ln s after 1, 3, 6, 12 h: "
              + ", ".join(f"{v:.2f}" for v in sl))
    out["link"] = links
    fan = load_card(ROOT / "models" / "alni-1to1-400rpm-fan.toml")
    lo, hi = fan.mill.rpm_max / 3, fan.mill.rpm_max
    out["fan_link_6h"] = {"rpm_low": lo, "rpm_high": hi, "low": plant_link(fan, lo, (6.0,), a.particles)[0],
                          "high": plant_link(fan, hi, (6.0,), a.particles)[0]}
    print(f"fan card after 6 h: slope {out['fan_link_6h']['low']:.2f} at {lo:g} rpm, {out['fan_link_6h']['high']:.2f} at {hi:g} rpm")
    if not a.no_results:
        from bmctl.results import write_results

        path = write_results("moments_plant_shape", out, settings={
            "card": CARD.name, "rpm": rpm, "particles": a.particles, "seeds": list(range(a.seeds)),
            "hours": [1.0, 12.0]}, command=COMMAND)
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
