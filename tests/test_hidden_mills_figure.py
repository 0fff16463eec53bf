"""``benchmarks/hidden_mills.py --figure``: one panel per mill from a results file's step logs."""

from __future__ import annotations

from tests.conftest import load_benchmark


def test_figure_draws_every_mill_from_the_step_logs(tmp_path):
    steps = [{"t_h": 0.5 * k, "rpm": 300.0 if k < 3 else 0.0, "mill_min": 30.0 if k < 3 else 0.0,
              "plant_s_mean_um": 40.0 + k, "estimate_s_mean_um": 40.5 + k} for k in range(6)]
    rec = {"command": "python benchmarks/hidden_mills.py",
           "cases": [{"case": n, "steps": steps, "target_s_mean_um": 44.0, "final_s_mean_um": 45.0,
                      "error_pct": 2.27} for n in "ABCDE"]}
    out = load_benchmark("hidden_mills").figure(rec, tmp_path / "f.png")
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000
    assert [p.name for p in tmp_path.iterdir()] == ["f.png"]  # written atomically, nothing left beside it
