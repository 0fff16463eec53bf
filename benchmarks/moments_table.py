"""The held-out accuracy of every shipped moment-coefficient file, as docs/moments.md (Sec. 6) tabulates it.

    python benchmarks/moments_table.py

``bmctl identify`` measures the held-out NRMSE of the coefficients it fits and stores it in the
coefficient file (``[validation] mean`` and ``max``, with the schedules, seeds and particles). This
script gathers those tables of ``models/*.moments.toml`` into ``results/moments_shipped.json`` (in
percent) and prints the Markdown table of docs/moments.md with its result markers.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

MOMENTS = ("s_mean_um", "s_std_um", "r_mean", "r_std", "temperature_c")


def main() -> None:
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
