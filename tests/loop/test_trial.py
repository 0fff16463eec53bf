"""Closed-loop trials: outputs, resume after interruption, bad scenario files."""

import json
from pathlib import Path

import pytest

from bmctl.cli import main
from bmctl.trial import run_trial, trajectory_header

from ..conftest import ROOT

SMALL = """
model = "{root}/models/alni-1to1-300rpm-lab.toml"
hours = 2
target = {{ s_mean_um = 50.0 }}
[scenario]
name = "small"
description = "two hours of MPC on a small plant"
[plant]
particles = 1000
gamma_factor = 1.3
delta_factor = 0.7
[sampling]
every_h = 1.0
particles = 200
[estimator]
particles = 300
[controller]
config = "{root}/controllers/mpc-fast.toml"
"""


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    d = tmp_path_factory.mktemp("sc")
    p = d / "small.toml"
    p.write_text(SMALL.format(root=ROOT))
    return p


@pytest.fixture(scope="module")
def one_step(small, tmp_path_factory):
    """A trial of ``small`` (seed 1) stopped after its first interval, as a crash would leave it."""
    out = tmp_path_factory.mktemp("one") / "o"
    assert run_trial(small, out, seed=1, max_steps=1) == {"interrupted_at_step": 1}
    return out


def _copy(folder, tmp_path):
    import shutil

    return Path(shutil.copytree(folder, tmp_path / "o"))


def _rows(path):
    return path.read_text().splitlines()


@pytest.mark.slow
def test_trial_outputs_and_resume_identical(small, tmp_path):
    full = tmp_path / "full"
    summary = run_trial(small, full, seed=5)
    for key in ("target", "final_true", "final_error", "max_temperature_c", "temperature_violations", "energy_kj",
                "batch_h", "solver_failures", "fallbacks"):
        assert key in summary
    assert json.loads((full / "summary.json").read_text())["batch_h"] == pytest.approx(2.0)
    rows = _rows(full / "trajectory.csv")
    assert rows[0].split(",") == trajectory_header()
    assert len(rows) == 1 + 4  # 0.5 h intervals
    assert (full / "trial.png").read_bytes()[:4] == b"\x89PNG"
    # interrupted after 2 steps, then resumed: the same trajectory (timing columns aside)
    part = tmp_path / "part"
    assert run_trial(small, part, seed=5, max_steps=2) == {"interrupted_at_step": 2}
    assert len(_rows(part / "trajectory.csv")) == 3
    # a row written after the last checkpoint (killed between the two writes) is dropped on resume
    with open(part / "trajectory.csv", "a") as fh:
        fh.write("garbage\n")
    assert run_trial(small, part, seed=5, resume=True, max_steps=1) == {"interrupted_at_step": 3}
    # killed mid-write of the next row: the torn row (no newline) is dropped on resume
    with open(part / "trajectory.csv", "a") as fh:
        fh.write("3,2,300,0.5,61.")
    run_trial(small, part, seed=5, resume=True)
    strip = lambda lines: [",".join(r.split(",")[:-3]) for r in lines]  # noqa: E731 - drop ms/status/fallback
    assert strip(_rows(part / "trajectory.csv")) == strip(rows)
    assert not list(part.glob("*.pkl"))


@pytest.mark.slow
def test_checkpoint_is_plain_data(one_step):
    import numpy as np

    out = one_step
    with np.load(out / "checkpoint.npz", allow_pickle=False) as z:  # raises if any entry needs pickle
        assert all(z[k].dtype != object for k in z.files)


@pytest.mark.slow
@pytest.mark.parametrize("target,content", [
    ("checkpoint.npz", b"PK\x03\x04 not really a zip"),
    ("checkpoint.npz", None),  # truncated to half its length
    ("trial.json", b'{"scenario": "x", "se'),
])
def test_resume_refuses_damaged_files_one_line(small, one_step, tmp_path, capsys, target, content):
    out = _copy(one_step, tmp_path)
    f = out / target
    f.write_bytes(f.read_bytes()[: f.stat().st_size // 2] if content is None else content)
    capsys.readouterr()
    rc = main(["trial", str(small), "--resume", str(out), "--seed", "1", "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2
    assert len(err.strip().splitlines()) == 1 and target in err, err


@pytest.mark.slow
def test_resume_refuses_other_seed(small, one_step, tmp_path):
    out = _copy(one_step, tmp_path)
    rc = main(["trial", str(small), "--resume", str(out), "--seed", "2", "--no-progress"])
    assert rc == 2


@pytest.mark.parametrize("edit,expect", [
    (("hours = 2", "hours = -2"), "hours"),
    (("gamma_factor = 1.3", "gamma_factor = nan"), "plant.gamma_factor"),
    (("s_mean_um = 50.0", "s_size = 50.0"), "target.s_size"),
    (("mpc-fast.toml", "nope.toml"), "not found"),
    (("[plant]", "[plant"), "malformed TOML"),
    (("particles = 1000", "particles = 1000\ncolour = 1"), "plant.colour: unknown field"),
])
def test_bad_scenario_one_line_exit2(small, tmp_path, capsys, edit, expect):
    text = small.read_text()
    assert edit[0] in text
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace(edit[0], edit[1], 1))
    out = tmp_path / "o"
    rc = main(["trial", str(bad), "--out", str(out), "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2
    assert len(err.strip().splitlines()) == 1 and err.startswith("bmctl: error:") and expect in err, err
    assert not out.exists()


@pytest.mark.parametrize("name", sorted(p.name for p in (ROOT / "scenarios").glob("trial-*.toml")))
def test_shipped_scenarios_validate(name):
    from bmctl.scenario import load_scenario

    sc = load_scenario(ROOT / "scenarios" / name)
    assert sc.scenario.description and "\n" not in sc.scenario.description
