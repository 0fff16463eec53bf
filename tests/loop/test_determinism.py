"""Same seed, same output: a closed-loop trial run with cold compile caches (the plant's numba
kernels and the MPC's compiled solvers absent, so the numpy plant code and casadi's interpreter
run while gcc and numba compile in the background) writes the same numbers as one run with every
cache warm, each in a fresh process, with different BLAS/OpenMP thread counts."""

import csv
import io
import json
import os
import subprocess
import sys

import pytest

from ..conftest import ROOT, TEST_CFLAGS

SCENARIO = """
model = "{root}/models/alni-1to1-300rpm-lab.toml"
hours = 3
target = {{ s_mean_um = 45.0 }}
[scenario]
name = "cold-warm"
description = "three hours of MPC on a small plant"
[plant]
particles = 2000
gamma_factor = 1.2
delta_factor = 0.8
[sampling]
every_h = 1.0
particles = 200
[estimator]
particles = 300
[controller]
config = "{root}/controllers/mpc-nominal.toml"
"""

TIMING = {"solve_ms"}  # wall-clock columns: the only ones allowed to differ

# `python -m bmctl` with the tests' gcc flags (conftest.TEST_CFLAGS, -O0): the exact-Hessian library compiles
# in ~15 s instead of ~100 s; what is checked is that cold and warm caches (interpreted, then compiled code)
# give the same trial.
BMCTL = ["-c", f"import sys; from bmctl.control import cache; cache.CFLAGS = {TEST_CFLAGS!r}; "
               "from bmctl.cli import main; sys.exit(main())"]


def _trial(tmp_path, name, env_extra):
    env = {k: v for k, v in os.environ.items() if k != "BMCTL_COMPILE"}
    env.update({"PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg", "NUMBA_CACHE_DIR": str(tmp_path / "numba"),
                "XDG_CACHE_HOME": str(tmp_path / "xdg"), "BMCTL_MPC_COMPILE": "1", **env_extra})
    out = tmp_path / name
    proc = subprocess.run([sys.executable, *BMCTL, "trial", str(tmp_path / "sc.toml"), "--seed", "3",
                           "--out", str(out), "--no-progress"], env=env, capture_output=True, text=True, timeout=1800)
    assert proc.returncode == 0, proc.stderr
    return out, proc.stderr


def _table(path):
    rows = list(csv.DictReader(io.StringIO(path.read_text(encoding="utf-8"))))
    return [{k: v for k, v in r.items() if k not in TIMING} for r in rows]


def _summary(path):
    s = json.loads(path.read_text(encoding="utf-8"))
    return {k: v for k, v in s.items() if not k.endswith("_ms")}


@pytest.mark.slow
def test_trial_is_identical_with_cold_and_warm_compile_caches(tmp_path):
    (tmp_path / "sc.toml").write_text(SCENARIO.format(root=ROOT), encoding="utf-8")
    cold, _ = _trial(tmp_path, "cold", {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"})
    # fill both caches in the foreground (waits for any compile the cold run started)
    _trial(tmp_path, "fill", {"BMCTL_MPC_COMPILE": "wait", "BMCTL_COMPILE": "now"})
    assert list((tmp_path / "numba").rglob("*.nbi")), "numba cache still empty"
    assert list((tmp_path / "xdg" / "bmctl" / "mpc").glob("mpc-warm-*.so")), "no compiled MPC solver"
    warm, err = _trial(tmp_path, "warm", {"OMP_NUM_THREADS": "2", "OPENBLAS_NUM_THREADS": "2"})
    # every library loads: the Gauss-Newton warm solver's too (its Hessian is generated into it)
    assert "did not load" not in err and "stopped" not in err, err
    assert _table(cold / "trajectory.csv") == _table(warm / "trajectory.csv")
    assert _summary(cold / "summary.json") == _summary(warm / "summary.json")
    # the timing column aside, the files are byte for byte the same
    skip = (cold / "trajectory.csv").read_text(encoding="utf-8").splitlines()[0].split(",").index("solve_ms")
    strip = lambda p: [",".join(c for i, c in enumerate(line.split(",")) if i != skip)  # noqa: E731
                       for line in p.read_text(encoding="utf-8").splitlines()]
    assert strip(cold / "trajectory.csv") == strip(warm / "trajectory.csv")
    # and the plant's and the estimator's states to the last bit (numpy engine cold, compiled warm)
    import numpy as np

    with np.load(cold / "checkpoint.npz") as a, np.load(warm / "checkpoint.npz") as b:
        keys = [k for k in a.files if k.startswith(("/mill/", "/estimator/"))]
        assert any(k.startswith("/mill/") for k in keys) and keys == [k for k in b.files if k in keys]
        for k in keys:
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)
