"""What an operator running a campaign sees: the report's estimate is the status's, and a particle
table entered a second time is refused."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from bmctl import campaign as cp
from bmctl.errors import InputError
from bmctl.measure.tables import ParticleTable

ROOT = Path(__file__).resolve().parents[2]
CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
RECIPE = ROOT / "controllers" / "recipe-300rpm-continuous.toml"


def _table(seed: int, n: int = 60) -> ParticleTable:
    rng = np.random.default_rng(seed)
    return ParticleTable.from_size_aspect(rng.lognormal(np.log(45.0), 0.45, n), rng.uniform(0.0, 0.12, n))


def test_report_estimate_now_lists_every_status_quantity(tmp_path):
    d = tmp_path / "c"
    cp.init(d, CARD, RECIPE, {"d50_um": 45.0}, hours=2.0, particles=100)
    cp.log(d, rpm=300.0, hours=0.5)
    est = cp.status(d)["estimate"]
    assert "energy_mult" in est
    page = cp.report(d).read_text(encoding="utf-8")
    now = page.split("<h2>Estimate now</h2>")[1].split("<h2>")[0]
    shown = re.findall(r"<td>([a-z_0-9]+)</td>", now)
    assert "energy_mult" in shown
    assert f"{est['energy_mult']:.4g}" in now


def test_a_table_entered_again_is_refused_in_one_line(tmp_path):
    """One particle table entered by two ``sample`` commands would read as a sample twice its size,
    as the same file named twice in one command does (refused there)."""
    d = tmp_path / "c"
    cp.init(d, CARD, RECIPE, {"d50_um": 45.0}, hours=2.0, particles=100)
    cp.log(d, rpm=300.0, hours=1.0)
    cp.sample(d, 0.5, [_table(1)])
    cp.sample(d, 0.5, [_table(2)])  # another sample at the same time: kept
    for at in (0.5, 1.0):
        with pytest.raises(InputError, match=r"the same particles as sample 1 at 0\.5 h") as e:
            cp.sample(d, at, [_table(1)])
        assert "\n" not in str(e.value)
    assert cp.status(d)["counts"]["samples"] == 2
