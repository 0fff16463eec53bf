"""Time `advise` on a campaign: the first call and warm calls, in one process and in fresh processes.

    python benchmarks/campaign_advise.py [--controller controllers/mpc-default.toml] [--repeat 3]

Prints the wall time of each advise (and the solver's share) and the database size.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main() -> None:
    from bmctl import campaign as cp
    from bmctl.measure.tables import ParticleTable

    ap = argparse.ArgumentParser()
    ap.add_argument("--controller", default=str(ROOT / "controllers" / "mpc-default.toml"))
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    d = Path(tempfile.mkdtemp()) / "c"
    cp.init(d, ROOT / "models" / "alni-1to1-300rpm-lab.toml", a.controller, {"d50_um": 45.0}, hours=12.0)
    rng = np.random.default_rng(0)
    with cp.Campaign(d) as c:
        for k in range(a.repeat + 1):
            t0 = time.perf_counter()
            adv = cp.advise(d, campaign=c)
            print(f"in-process advise {k}: {time.perf_counter() - t0:.2f} s (solve {adv['solve_ms'] / 1e3:.2f} s)")
            cp.log(d, adv["next"]["rpm"], 0.5, adv["next"]["mill_min"] / 30.0, campaign=c)
            cp.sample(d, c.clock_h(), [ParticleTable.from_size_aspect(rng.lognormal(np.log(50), 0.45, 300),
                                                                       rng.uniform(0, 0.1, 300))], campaign=c)
    for k in range(a.repeat):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "bmctl", "campaign", "advise", str(d)], cwd=ROOT, check=True,
                       capture_output=True)
        print(f"fresh-process advise {k}: {time.perf_counter() - t0:.2f} s (CLI, imports included)")
    print(f"database: {(d / 'campaign.sqlite').stat().st_size / 1e6:.2f} MB after {a.repeat + 1} intervals")


if __name__ == "__main__":
    main()
