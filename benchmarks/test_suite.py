"""Time the test suites as README.md states them, and write ``results/test_suite.json``.

    python benchmarks/test_suite.py                 # the quick suite, then the full suite
    python benchmarks/test_suite.py --only quick    # one of them (the other's entry is kept)

quick: ``python -m pytest -m "not slow" -n auto``; full: ``python -m pytest -n auto`` (pytest-xdist,
one worker per core). For each: the tests run (passed, skipped, failed), wall seconds, CPU seconds
of the pytest processes (user + system of the children), the names of failed tests (at most 20) and the load average before and after,
since timings on a shared machine are inflated by the others' load.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

#: the commands as README.md gives them
SHOWN = {"quick": 'python -m pytest -m "not slow" -n auto', "full": "python -m pytest -n auto"}
SUITES = {
    "quick": [sys.executable, "-m", "pytest", "-m", "not slow", "-n", "auto", "-p", "no:cacheprovider"],
    "full": [sys.executable, "-m", "pytest", "-n", "auto", "-p", "no:cacheprovider"],
}


def counts(text: str) -> dict[str, int]:
    """``passed``, ``skipped``, ``failed``, ``errors`` ... from pytest's last summary line.

    Examples
    --------
    >>> counts("== 652 passed, 2 skipped, 178 deselected in 93.1s ==")
    {'passed': 652, 'skipped': 2, 'deselected': 178}
    """
    out = {}
    for n, what in re.findall(r"(\d+) (passed|skipped|failed|errors?|deselected|xfailed|xpassed)", text):
        out["errors" if what.startswith("error") else what] = int(n)
    return out


def run_suite(name: str) -> dict:
    """Run one suite from the repository root; its counts, wall and CPU seconds and load."""
    load0 = os.getloadavg()
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(SUITES[name], cwd=ROOT, capture_output=True, text=True,
                          env={**os.environ, "MPLBACKEND": "Agg"})
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    summary = [ln for ln in (proc.stdout + proc.stderr).splitlines() if re.search(r"\d+ (passed|failed)", ln)]
    tail = summary[-1:] or [""]
    failures = [ln.strip() for ln in proc.stdout.splitlines() if ln.startswith(("FAILED ", "ERROR "))][:20]
    return {"command": SHOWN[name],
            "returncode": proc.returncode, **counts(tail[0]), "failures": failures, "wall_s": round(wall, 1),
            "cpu_s": round((r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime), 1),
            "wall_min": round(wall / 60, 1), "cpus": os.cpu_count(), "load_before": list(load0),
            "load_after": list(os.getloadavg())}


def main() -> None:
    from bmctl.results import load_results, write_results

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=sorted(SUITES), default=None, help="run one suite (keep the other's entry)")
    args = ap.parse_args()
    try:
        values = {k: v for k, v in load_results("test_suite").items() if k in SUITES}
    except (FileNotFoundError, OSError, ValueError, KeyError):
        values = {}
    for name in [args.only] if args.only else list(SUITES):
        values[name] = run_suite(name)
        print(f"{name}: {values[name]}")
    write_results("test_suite", values, settings={"suites": SHOWN},
                  command="python benchmarks/test_suite.py" + (f" --only {args.only}" if args.only else ""))


if __name__ == "__main__":
    main()
