"""The held-out accuracy of every shipped moment-coefficient file, as docs/moments.md (Sec. 6) tabulates it.

    python benchmarks/moments_table.py

``bmctl identify`` measures the held-out NRMSE of the coefficients it fits and stores it in the
coefficient file (``[validation] mean`` and ``max``, with the schedules, seeds and particles). This
script gathers those tables of ``models/*.moments.toml`` into ``results/moments_shipped.json`` (in
percent) and prints the Markdown table of docs/moments.md with its result markers. It also
gathers the off-card check that ``bmctl identify`` stores (``[validation.off_card]``: the model
told the plant's γ and δ; ``[validation.off_card_p1]``: not told) and the identified coefficients.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

MOMENTS = ("s_mean_um", "s_std_um", "r_mean", "r_std", "temperature_c")
#: off-card plants of [validation.off_card]: key in the coefficient file -> key in the results file
OFF_CARD = {"recipe-g1.3-d0.7": "g13_d07", "recipe-g0.7-d1.3": "g07_d13"}


def off_card(table: dict) -> dict:
    """{plant: {moment: percent}} of an ``[validation.off_card*]`` table."""
    out = {}
    for key, value in table.items():
        plant, _, moment = key.partition(", ")
        out.setdefault(OFF_CARD.get(plant, plant), {})[moment] = round(100 * value, 3)
    return out


def main(argv=None) -> None:
    import argparse

    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args(argv)  # no options: --help, or refused
    from bmctl.config import read_toml
    from bmctl.results import marked, write_results

    cards = {}
    for p in sorted((ROOT / "models").glob("*.moments.toml")):
        d = read_toml(p)
        v, i = d["validation"], d["identification"]
        cards[p.name.removesuffix(".moments.toml")] = {
            "mean_pct": {k: round(100 * v["mean"][k], 2) for k in MOMENTS},
            "max_pct": {k: round(100 * v["max"][k], 2) for k in MOMENTS},
            "defaults_mean_pct": {k: round(100 * v["defaults_mean"][k], 2) for k in MOMENTS if k in v.get(
                "defaults_mean", {})},
            "off_card_pct": off_card(v.get("off_card", {})),
            "off_card_p1_pct": off_card(v.get("off_card_p1", {})),
            "off_card_mean_pct": round(100 * sum(v.get("off_card", {}).values()) / max(len(v.get("off_card", {})), 1), 2),
            "coefficients": dict(d["coefficients"]),
            "schedules": v["schedules"], "seeds": v["seeds"], "particles": v["particles"],
            "command": i["command"], "date_utc": i["date_utc"]}
    path = write_results("moments_shipped", {"cards": cards}, settings={"files": "models/*.moments.toml"},
                         command="python benchmarks/moments_table.py")
    print("| card | s_mean | s_std | r_mean | r_std | temperature |\n|---|---|---|---|---|---|")
    for name, c in cards.items():
        cells = []
        for k in MOMENTS:
            fmt = "{:.2f}" if k in ("r_mean", "r_std") else "{:.1f}"
            cells.append(f"{marked('moments_shipped', f'cards.{name}.mean_pct.{k}', c['mean_pct'][k], fmt)} % "
                         f"({marked('moments_shipped', f'cards.{name}.max_pct.{k}', c['max_pct'][k], '{:.1f}')})")
        print(f"| {name} | " + " | ".join(cells) + " |")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
