"""Numbers behind docs/model.md and docs/fidelity.md that say what the plant is.

1. The paper's shape-change law, eqns (11)-(14), with the card's ``strain_efficiency`` η_ε:
   r̄ at 12 h on the lab card's recipe with η_ε as on the card and with η_ε = 0, over seeds;
   and the literal law (η_ε = 1, clipped at ``max_strain``): r̄ after 1 h.
2. What the plant conserves: Σ s² of the represented powder (the 2-D reading of eqn 2), so
   Σ s³ (sphere-equivalent volume) changes: its ratio at 2 h to the start, and Σ s²'s.
3. The powder mass the card implies (ball count × ball mass / ball-to-powder ratio) against the
   paper's stated total loading.

    python benchmarks/model_facts.py            # ~3 min on one core; writes results/model_facts.json
"""

from __future__ import annotations

import argparse
import sys
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bmctl.config import card_schedule, load_card  # noqa: E402
from bmctl.plant.plant import Plant  # noqa: E402

CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
COMMAND = "python benchmarks/model_facts.py"
PAPER_TOTAL_LOADING_G = 32.0  # paper-facts.toml [experiment] total_loading_g


def with_partition(card, **fields):
    d = card.model_dump()
    d["partition"].update(fields)
    return type(card).model_validate(d)


def r_mean_at_end(card, seed: int, particles: int, hours: float) -> float:
    plant = Plant(card, np.random.default_rng(seed), particles)
    plant.run_schedule(card_schedule(card, hours), hours)
    return float(plant.moments()["r_mean"])


def conserved(card, seed: int, particles: int, hours: float) -> dict:
    """Σ s³ of the represented powder at ``hours`` relative to the start (one run); Σ s² is the
    plant's invariant X (``Plant.total_area``, held fixed by construction)."""
    plant = Plant(card, np.random.default_rng(seed), particles)

    def totals():
        s = plant.s
        X = plant.total_area  # the represented Σ s² (m²), the plant's invariant
        return X, X * float(np.sum(s**3) / np.sum(s**2))  # Σ s³ = X · (Σ s³ / Σ s²) of the sample

    a2, a3 = totals()
    plant.advance(card.process.rpm, hours)
    b2, b3 = totals()
    return {"sum_s3_ratio": b3 / a3, "sauter_mean_um_start": 1e6 * a3 / a2,
            "sauter_mean_um_end": 1e6 * b3 / b2}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--particles", type=int, default=20000)
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--no-results", action="store_true")
    a = ap.parse_args(argv)
    card = load_card(CARD)
    part = card.partition
    seeds = list(range(a.seeds))
    with_law = [r_mean_at_end(card, s, a.particles, 12.0) for s in seeds]
    without = [r_mean_at_end(with_partition(card, strain_efficiency=0.0), s, a.particles, 12.0) for s in seeds]
    literal_1h = [r_mean_at_end(with_partition(card, strain_efficiency=1.0), s, a.particles // 4, 1.0) for s in seeds[:2]]
    cons = conserved(card, 0, a.particles, 2.0)
    plant = Plant(card, np.random.default_rng(0), 100)
    paper = tomllib.loads((ROOT.parent / "shared" / "reference" / "paper-facts.toml").read_text()) \
        if (ROOT.parent / "shared" / "reference" / "paper-facts.toml").exists() else None
    values = {
        "shape_change": {
            "strain_efficiency": part.strain_efficiency, "max_strain": part.max_strain,
            "equiaxing_efficiency": part.equiaxing_efficiency,
            "rounding_over_drift": part.equiaxing_efficiency / part.strain_efficiency,
            "r_mean_12h_with": float(np.mean(with_law)), "r_mean_12h_without": float(np.mean(without)),
            "r_mean_12h_with_seeds": with_law, "r_mean_12h_without_seeds": without,
            "r_mean_12h_seed_min": float(min(with_law + without)), "r_mean_12h_seed_max": float(max(with_law + without)),
            "r_mean_12h_sd_with": float(np.std(with_law, ddof=1)), "r_mean_12h_sd_without": float(np.std(without, ddof=1)),
            "effect": float(np.mean(with_law) - np.mean(without)),
            "effect_se": float(np.sqrt(np.var(with_law, ddof=1) / len(seeds) + np.var(without, ddof=1) / len(seeds))),
            "r_mean_1h_literal": float(np.mean(literal_1h)),
        },
        "conservation_2h": cons,
        "powder": {"powder_g": 1e3 * plant.powder_kg, "paper_total_loading_g": PAPER_TOTAL_LOADING_G,
                   "paper_over_card": PAPER_TOTAL_LOADING_G / (1e3 * plant.powder_kg),
                   "paper_stated": bool(paper and paper["experiment"]["total_loading_g"] == PAPER_TOTAL_LOADING_G)},
    }
    sc = values["shape_change"]
    print(f"r̄ at 12 h (lab recipe, M = {a.particles}, seeds {seeds}): with eqns 11-14 (η_ε = {part.strain_efficiency:g}) "
          f"{sc['r_mean_12h_with']:.4f} ± {sc['r_mean_12h_sd_with']:.4f}, without {sc['r_mean_12h_without']:.4f} ± "
          f"{sc['r_mean_12h_sd_without']:.4f}; effect {sc['effect']:+.4f} ± {sc['effect_se']:.4f}; "
          f"literal law (η_ε = 1): r̄ {sc['r_mean_1h_literal']:.3f} after 1 h")
    print(f"2 h at {card.process.rpm:g} rpm: Σs² fixed, Σs³ × {cons['sum_s3_ratio']:.3f} "
          f"(Sauter mean {cons['sauter_mean_um_start']:.1f} → {cons['sauter_mean_um_end']:.1f} µm)")
    print(f"powder: {values['powder']['powder_g']:.2f} g on the card, paper's total loading {PAPER_TOTAL_LOADING_G:g} g")
    if not a.no_results:
        from bmctl.results import write_results

        write_results("model_facts", values, settings={"card": CARD.name, "particles": a.particles, "seeds": seeds,
                                                        "hours": 12.0, "literal_particles": a.particles // 4},
                      command=COMMAND)
    return 0


if __name__ == "__main__":
    sys.exit(main())
