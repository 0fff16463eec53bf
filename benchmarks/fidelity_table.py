"""Numbers behind docs/fidelity.md: the paper's Sec. 4.2 claims measured on the three cards.

Runs each shipped card for 12 h (its own recipe: continuous, or 30 min / 10 min at 400 rpm),
recording hourly, and prints number-, area- and volume-weighted size statistics, r
statistics, temperatures, event rates per milling hour, and distribution-shape tests
(Kolmogorov-Smirnov against a fitted normal and log-normal, and a two-component Gaussian
mixture in ln s against one component by BIC) on a 3000-particle subsample.

    python benchmarks/fidelity_table.py --particles 20000 --seed 2024    # about 1 min on one core
    python benchmarks/fidelity_table.py --particles 20000 --seed 2024 --no-equiaxing   # the paper's shape law alone

Writes ``results/fidelity_table.json`` (``fidelity_table_no_equiaxing.json``): per card the hourly
series, the shape tests, event rates and temperatures, and the derived numbers docs/fidelity.md
quotes (``derived``: peaks over 1-6 h and their hours, 6 h and 12 h values, ranges over hours).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy import stats

from bmctl.config import card_schedule, load_card
from bmctl.plant.plant import Plant

ROOT = Path(__file__).resolve().parents[1]
CARDS = ("alni-1to1-300rpm-lab", "alni-1to1-400rpm-fan", "alni-1to3-300rpm-hadjiafxenti")
SHORT = {"alni-1to1-300rpm-lab": "lab", "alni-1to1-400rpm-fan": "400", "alni-1to3-300rpm-hadjiafxenti": "1:3"}
KEYS = ("s_mean_um", "s_std_um", "s_mode_um", "s_mode_area_um", "s_mean_area_um", "d10_um", "d50_um", "d90_um",
        "span", "r_mean", "r_std", "r_mode")


def mixture2_bic_gain(x: np.ndarray, iters: int = 300) -> tuple[float, float, float, float]:
    """BIC(one Gaussian) - BIC(two-component Gaussian mixture) of x (> 0 favours two), the weight of the
    lower component and the two component means (of x)."""
    n = x.size
    ll1 = stats.norm.logpdf(x, x.mean(), x.std()).sum()
    lo, hi = np.quantile(x, [0.25, 0.75])
    w, m, s = np.array([0.5, 0.5]), np.array([lo, hi]), np.array([x.std(), x.std()]) / 2
    for _ in range(iters):  # EM
        d = w * stats.norm.pdf(x[:, None], m, s)
        g = d / d.sum(1, keepdims=True)
        nk = g.sum(0)
        w, m = nk / n, (g * x[:, None]).sum(0) / nk
        s = np.sqrt(np.maximum((g * (x[:, None] - m) ** 2).sum(0) / nk, 1e-6))
    ll2 = np.log((w * stats.norm.pdf(x[:, None], m, s)).sum(1)).sum()
    lo_k = int(np.argmin(m))
    return (float((-2 * ll1 + 2 * np.log(n)) - (-2 * ll2 + 5 * np.log(n))), float(w[lo_k]), float(m.min()),
            float(m.max()))


#: particles of the subsample the shape tests draw
SUBSAMPLE = 3000


def shape_tests(s_um: np.ndarray, rng: np.random.Generator) -> dict[str, float]:
    """KS p-values (normal, log-normal), log-likelihood gain of log-normal over normal, mixture BIC gain."""
    x = rng.choice(s_um, SUBSAMPLE, replace=False)
    lx = np.log(x)
    ll_n = stats.norm.logpdf(x, x.mean(), x.std()).sum()
    ll_ln = stats.norm.logpdf(lx, lx.mean(), lx.std()).sum() - lx.sum()
    bic, w_lo, m_lo, m_hi = mixture2_bic_gain(lx)
    return {"ks_p_normal": stats.kstest(x, "norm", (x.mean(), x.std())).pvalue,
            "ks_p_lognormal": stats.kstest(lx, "norm", (lx.mean(), lx.std())).pvalue,
            "ll_lognormal_minus_normal": ll_ln - ll_n, "bic_gain_2_components": bic,
            "lower_hump_weight": w_lo, "lower_hump_median_um": np.exp(m_lo), "upper_hump_median_um": np.exp(m_hi)}


def without_equiaxing(card):
    """A copy of ``card`` with the equiaxing law switched off (docs/model.md, eqns 11-14)."""
    d = card.model_dump()
    d["partition"]["equiaxing_efficiency"] = 0.0
    return type(card).model_validate(d)


def fracture_probability(plant: Plant, s_um: float, n: int = 20000) -> float:
    """Share of impacts on a particle of ``s_um`` (r = 0.05) that break it, against partners drawn
    from the plant's population, in the plant's present state (temperature, hardening)."""
    from bmctl.plant.kinematics import kinematics

    rng = np.random.default_rng(12345)
    kin = kinematics(plant.card, plant.card.process.rpm)
    k = rng.integers(0, plant.M, n)
    si, ri = np.full(n, s_um * 1e-6), np.full(n, 0.05)
    u_in = plant.kernels.sample_energies(rng, kin.energy_scale, n)
    c2 = plant.kernels.sample_cos2psi(plant, rng, n)
    out, _ = plant.kernels.impact(plant, kin, si, ri, plant.s[k], plant.r[k], u_in, c2, rng)
    return float(out.frac[:n].mean())


def run_card(name: str, particles: int, seed: int, equiaxing: bool = True) -> dict:
    card = load_card(ROOT / "models" / f"{name}.toml")
    if not equiaxing:
        card = without_equiaxing(card)
    segments = card_schedule(card, 12.0)
    plant = Plant(card, np.random.default_rng(seed), particles)
    rng = np.random.default_rng(seed + 1)  # subsamples of the shape tests
    tests: list[dict] = []
    pfrac: dict[str, float] = {}

    def on_record(p):
        tests.append(shape_tests(p.s * 1e6, rng))
        if len(tests) == 3:  # at 2 h: where the welded hump peaks on the lab card
            pfrac.update({f"{x:g}": fracture_probability(p, x) for x in (25.0, 40.0, 140.0)})

    recs = plant.run_schedule(segments, 1.0, on_record=on_record)
    milling_h = sum(h for h, rpm in segments if rpm > 0)
    return {"series": {k: np.array([r.moments[k] for r in recs]) for k in KEYS},
            "temperature_c": np.array([r.temperature_c for r in recs]), "tests": tests,
            "bonds_per_h": plant.counts.bonds / milling_h, "fractures_per_h": plant.counts.fractures / milling_h,
            "fracture_probability_2h": pfrac}


def derived(res: dict) -> dict:
    """The numbers docs/fidelity.md quotes, from one card's run (hour index = hours, 0..12)."""
    ser, T = res["series"], res["temperature_c"]
    early = slice(1, 7)  # 1-6 h

    def peak(key):
        v = np.asarray(ser[key])
        k = 1 + int(np.argmax(v[early]))
        return {"value": float(v[k]), "hour": k, "at_12h": float(v[12]), "at_0h": float(v[0]), "at_6h": float(v[6]),
                "at_1h": float(v[1]), "at_2h": float(v[2])}

    out = {k: peak(k) for k in KEYS}
    out["d90_minus_d10"] = {"at_peak_d50": float(ser["d90_um"][out["d50_um"]["hour"]] - ser["d10_um"][out["d50_um"]["hour"]]),
                            "at_12h": float(ser["d90_um"][12] - ser["d10_um"][12])}
    out["span_at_peak_d50"] = float(ser["span"][out["d50_um"]["hour"]])
    out["s_std_at_peak_mean"] = float(ser["s_std_um"][out["s_mean_um"]["hour"]])
    out["r_std_at_peak_r_mean"] = float(ser["r_std"][out["r_mean"]["hour"]])
    out["s_mode_max_1_6h"] = float(np.max(ser["s_mode_um"][early]))
    out["r_mode_max_after_1h"] = float(np.max(ser["r_mode"][1:]))
    tests = res["tests"][1:]
    out["tests"] = {
        "ll_gain_min": float(min(t["ll_lognormal_minus_normal"] for t in tests)),
        "ll_gain_max": float(max(t["ll_lognormal_minus_normal"] for t in tests)),
        "ks_p_lognormal_max": float(max(t["ks_p_lognormal"] for t in tests)),
        "ks_p_normal_max": float(max(t["ks_p_normal"] for t in tests)),
        "bic_gain_min": float(min(t["bic_gain_2_components"] for t in tests)),
        "bic_gain_max": float(max(t["bic_gain_2_components"] for t in tests)),
        "major_weight_min": float(min(max(t["lower_hump_weight"], 1 - t["lower_hump_weight"]) for t in tests)),
        "major_weight_max": float(max(max(t["lower_hump_weight"], 1 - t["lower_hump_weight"]) for t in tests)),
        "lower_hump_weight_1_4h_min": float(min(t["lower_hump_weight"] for t in tests[:4])),
        "lower_hump_weight_1_4h_max": float(max(t["lower_hump_weight"] for t in tests[:4])),
        "lower_hump_median_um_1_4h_min": float(min(t["lower_hump_median_um"] for t in tests[:4])),
        "lower_hump_median_um_1_4h_max": float(max(t["lower_hump_median_um"] for t in tests[:4])),
        "upper_hump_median_um_1_4h_min": float(min(t["upper_hump_median_um"] for t in tests[:4])),
        "upper_hump_median_um_1_4h_max": float(max(t["upper_hump_median_um"] for t in tests[:4])),
    }
    out["temperature_c"] = {"max": float(np.max(T)), "min_after_1h": float(np.min(T[1:])), "at_12h": float(T[12])}
    out["bonds_per_h"], out["fractures_per_h"] = float(res["bonds_per_h"]), float(res["fractures_per_h"])
    out["fracture_probability_2h"] = res["fracture_probability_2h"]
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--particles", type=int, default=20000)
    ap.add_argument("--seed", type=int, default=2024)
    ap.add_argument("--no-equiaxing", action="store_true", help="switch the equiaxing law off on every card")
    ap.add_argument("--no-results", action="store_true", help="print only")
    a = ap.parse_args(argv)
    if a.particles < SUBSAMPLE:
        ap.error(f"--particles: at least {SUBSAMPLE} (the shape tests draw a {SUBSAMPLE}-particle subsample; got {a.particles})")
    print(f"M = {a.particles}, seed {a.seed}; hourly values t = 0..12 h" + (", no equiaxing" if a.no_equiaxing else ""))
    record = {}
    for name in CARDS:
        res = run_card(name, a.particles, a.seed, not a.no_equiaxing)
        record[SHORT[name]] = {"series": {k: v.tolist() for k, v in res["series"].items()},
                               "temperature_c": res["temperature_c"].tolist(), "tests": res["tests"],
                               "derived": derived(res)}
        print(f"\n== {name}: bonds {res['bonds_per_h']:.0f} /milling h, fractures {res['fractures_per_h']:.0f} /milling h"
              f" (sample of M)")
        for k, v in res["series"].items():
            print(f"  {k:16s}" + " ".join(f"{x:7.3g}" for x in v))
        print(f"  {'temperature_c':16s}" + " ".join(f"{x:7.3g}" for x in res["temperature_c"]))
        for k in res["tests"][1]:
            print(f"  {k:26s}" + " ".join(f"{t[k]:8.2g}" for t in res["tests"][1:]))
    if not a.no_results:
        from bmctl.results import write_results

        stem = "fidelity_table_no_equiaxing" if a.no_equiaxing else "fidelity_table"
        write_results(stem, record, settings={"particles": a.particles, "seed": a.seed, "hours": 12.0,
                                              "equiaxing": not a.no_equiaxing, "cards": list(CARDS)},
                      command=f"python benchmarks/fidelity_table.py --particles {a.particles} --seed {a.seed}"
                              + (" --no-equiaxing" if a.no_equiaxing else ""))


if __name__ == "__main__":
    main()
