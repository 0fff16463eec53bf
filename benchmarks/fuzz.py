"""Long fuzz run of the ``bmctl`` CLI: hostile inputs, each case in its own subprocess.

The cases are those of tests/fuzzlib.py (mutated shipped cards, schedules, scenarios,
controllers, particle tables, micrographs, out-of-range flags, hostile campaign commands and
damaged campaign databases, damaged files of interrupted trials), drawn round-robin over
the kinds from seeds 0..N-1. Each case runs in a forked child of a worker that has imported
bmctl once (so a case costs its own work, not Python's start-up), with stdout and stderr
captured and a wall-clock limit; the outcome is classified by ``fuzzlib.classify``.

    nice -n 5 python benchmarks/fuzz.py --cases 2100 --workers 2

prints the counts by outcome (the table in docs/reliability.md), lists every case that is not
``clean`` or ``accepted-ok``, and writes ``results/fuzz.json`` (counts by kind and outcome, the
slowest case, wall and CPU seconds, the load; ``--json FILE`` adds every case's record).
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import signal
import sys
import tempfile
import time
import traceback
from pathlib import Path

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_v, "1")
os.environ.setdefault("MPLBACKEND", "Agg")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests import fuzzlib  # noqa: E402  (not tests/ on sys.path: tests/control would shadow python-control)

BAD = ("accepted-nonsense", "wrote-nonsense", "traceback", "hang", "unnamed", "unsafe")


def _preload() -> None:
    import bmctl.cli as cli

    cli._modules()  # every command module, numpy, scipy, pydantic
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot  # noqa: F401
    from bmctl.moments.model import make_moment_model

    for card in fuzzlib.CARDS:  # the derived laws' Monte Carlo is cached: a case pays for its own work only
        make_moment_model(str(card))


def _fixtures(kinds) -> None:
    """Build the campaigns and interrupted trials the campaign and resume cases copy (once, before
    the workers fork, so both share them; removed when this process exits)."""
    if {"campaign", "resume"} & set(kinds):
        fuzzlib.fixtures()


def run_case(kind: str, seed: int, timeout_s: float) -> dict:
    """Run one case in a forked child; returns its record (kind, seed, label, outcome, detail, seconds)."""
    case = fuzzlib.make_case(kind, seed)
    with tempfile.TemporaryDirectory(prefix="bmctl-fuzz-") as tmp:
        folder = Path(tmp)
        case.write(folder)
        out_f, err_f = folder / ".stdout", folder / ".stderr"
        t0 = time.monotonic()
        pid = os.fork()
        if pid == 0:  # the child: run the CLI in-process, report through fds and the exit status
            code = 1
            try:
                os.chdir(ROOT)
                os.environ.update(case.env)
                fo = os.open(out_f, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
                fe = os.open(err_f, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
                os.dup2(fo, 1)
                os.dup2(fe, 2)
                sys.stdout = os.fdopen(1, "w", buffering=1)
                sys.stderr = os.fdopen(2, "w", buffering=1)
                from bmctl.cli import main

                for argv in case.commands(folder):
                    code = main(argv)
                    if code != 0:
                        break
            except BaseException:  # noqa: BLE001 - anything escaping main is the finding
                traceback.print_exc()
                code = 99
            finally:
                try:
                    sys.stdout.flush()
                    sys.stderr.flush()
                finally:
                    os._exit(code if isinstance(code, int) and 0 <= code < 256 else 98)
        rc = None
        while time.monotonic() - t0 < timeout_s:
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                rc = os.waitstatus_to_exitcode(status)
                break
            time.sleep(0.02)
        if rc is None:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
        secs = time.monotonic() - t0
        stdout = out_f.read_text(errors="replace") if out_f.exists() else ""
        stderr = err_f.read_text(errors="replace") if err_f.exists() else ""
        if rc is not None and rc < 0:
            stderr += f"\nkilled by signal {-rc}"
            rc = 139
        outcome, detail = fuzzlib.classify(case, rc, stdout, stderr, folder / "out")
    return {"kind": kind, "seed": seed, "label": case.label, "argv": case.argv, "outcome": outcome,
            "detail": detail, "seconds": round(secs, 2)}


def _worker(job):
    kind, seed, timeout_s = job
    try:
        return run_case(kind, seed, timeout_s)
    except Exception as exc:  # the harness itself failed: report, do not hide
        return {"kind": kind, "seed": seed, "label": "harness", "argv": [], "outcome": "traceback",
                "detail": f"harness: {exc!r}", "seconds": 0.0}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=2100)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--timeout", type=float, default=60.0, help="per-case limit, s (default 60)")
    ap.add_argument("--kinds", default=",".join(fuzzlib.KINDS))
    ap.add_argument("--start", type=int, default=0, help="first case seed (default 0)")
    ap.add_argument("--json", default=None, help="write every case's record here")
    ap.add_argument("--no-results", action="store_true", help="do not write results/fuzz.json")
    args = ap.parse_args(argv)
    kinds = args.kinds.split(",")
    jobs = [(kinds[i % len(kinds)], args.start + i // len(kinds), args.timeout) for i in range(args.cases)]
    _preload()
    _fixtures(kinds)
    import multiprocessing as mp

    t0 = time.time()
    records = []
    with mp.get_context("fork").Pool(min(args.workers, 2)) as pool:
        for k, rec in enumerate(pool.imap_unordered(_worker, jobs, chunksize=4), 1):
            records.append(rec)
            if rec["outcome"] in BAD:
                print(f"[{rec['outcome']}] {rec['kind']}#{rec['seed']}: {rec['label']}: {rec['detail']}", flush=True)
            if k % 100 == 0:
                print(f"... {k}/{len(jobs)} cases, {time.time() - t0:.0f} s", file=sys.stderr, flush=True)
    counts = collections.Counter(r["outcome"] for r in records)
    by_kind = collections.defaultdict(collections.Counter)
    for r in records:
        by_kind[r["kind"]][r["outcome"]] += 1
    wall = time.time() - t0
    print(f"\n{len(records)} cases in {wall:.0f} s ({args.workers} workers, {args.timeout:g} s limit)")
    print("| outcome | " + " | ".join(kinds) + " | total |")
    print("|---|" + "---|" * (len(kinds) + 1))
    for o in fuzzlib.OUTCOMES:
        print(f"| {o} | " + " | ".join(str(by_kind[k][o]) for k in kinds) + f" | {counts[o]} |")
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(records, indent=1))
    if not args.no_results:
        from bmctl.results import write_results

        slowest = max(records, key=lambda r: r["seconds"])
        cpu = os.times()
        values = {
            "cases": len(records),
            "kinds": kinds,
            "total": {o: counts[o] for o in fuzzlib.OUTCOMES},
            "by_kind": {k: {o: by_kind[k][o] for o in fuzzlib.OUTCOMES} for k in kinds},
            "refused_one_line": counts["clean"],
            "bad": sum(counts[o] for o in BAD),
            "findings": [{k: r[k] for k in ("kind", "seed", "label", "outcome", "detail")}
                         for r in records if r["outcome"] in BAD],
            "slowest_s": slowest["seconds"],
            "slowest_case": f"{slowest['kind']}#{slowest['seed']}: {slowest['label']}",
            "wall_s": round(wall, 1),
            "cpu_s": round(cpu.children_user + cpu.children_system + cpu.user + cpu.system, 1),
            "loadavg": list(os.getloadavg()),
        }
        cmd = "nice -n 5 python benchmarks/fuzz.py" + (f" --cases {args.cases}" if args.cases != 2100 else "") + (
            f" --kinds {args.kinds}" if args.kinds != ",".join(fuzzlib.KINDS) else "")
        path = write_results("fuzz", values, settings={"cases": args.cases, "workers": args.workers,
                                                       "timeout_s": args.timeout, "start": args.start, "kinds": kinds},
                             command=cmd)
        print(f"wrote {path}")
        print("\n" + doc_table(values))
    return 1 if any(counts[o] for o in BAD) else 0


def doc_table(values: dict) -> str:
    """The table of docs/reliability.md (a row per kind, a column per outcome) with its markers
    into results/fuzz.json."""
    from bmctl.results import marked

    kinds, outs = values["kinds"], fuzzlib.OUTCOMES
    lines = ["| kind | " + " | ".join(outs) + " |", "|---|" + "---:|" * len(outs)]
    for k in kinds:
        lines.append(f"| {k} | " + " | ".join(marked("fuzz", f"by_kind.{k}.{o}", values["by_kind"][k][o], "{}")
                                             for o in outs) + " |")
    lines.append("| **total** | " + " | ".join(marked("fuzz", f"total.{o}", values["total"][o], "{}") for o in outs)
                 + " |")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
