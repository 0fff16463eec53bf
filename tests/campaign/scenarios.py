"""A short LQR trial scenario shared by the campaign tests (2 h, samples every hour, small plant)."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
LQR = ROOT / "controllers" / "lqr-baseline.toml"


def lqr_scenario(path: Path, extra: str = "") -> Path:
    path.write_text(f"""model = "{CARD}"
hours = 2.0
target = {{ s_mean_um = 40.0 }}
[scenario]
name = "campaign-lqr"
description = "LQR, 2 h, samples every hour"
[plant]
particles = 400
[sampling]
every_h = 1.0
particles = 120
[estimator]
particles = 100
{extra}
[controller]
config = "{LQR}"
""", encoding="utf-8")
    return path
