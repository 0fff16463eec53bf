"""`bmctl calibrate --params` fits model constants only, refused before any work; history typos are
named; the summary gives units and counts in words."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from bmctl.calibrate import run as run_module
from bmctl.calibrate.history import load_history
from bmctl.calibrate.params import parse_params
from bmctl.cli import main
from bmctl.config import load_card
from bmctl.errors import InputError

from tests.conftest import ROOT, card_path

LAB = card_path("alni-1to1-300rpm-lab")
HISTORY = ROOT / "examples" / "history-lab-300rpm.toml"
ALLOWED = "calibratable: alpha, beta, gamma, delta, material.bond_threshold_J_per_m"


@pytest.fixture
def no_work(monkeypatch):
    """Any calibration work fails the test: refusals must come before it."""
    def work(*a, **k):
        raise AssertionError("the calibration started")

    monkeypatch.setattr(run_module, "run_calibration", work)
    monkeypatch.setattr(run_module, "calibrate", work)


def _refused(capsys, tmp_path, params: str) -> str:
    out = tmp_path / "out"
    rc = main(["calibrate", str(LAB), str(HISTORY), "--params", params, "--workers", "0", "--out", str(out)])
    lines = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and lines[0].startswith("bmctl: error: --params: "), lines
    assert not out.exists()
    return lines[0]


@pytest.mark.parametrize("name, why", [
    ("process.rpm", "an operating setting"),
    ("mill.ball_count", "an integer"),
    ("simulation.particles", "an integer"),
    ("simulation.max_step_s", "a numerical setting"),
    ("validity.s_min_um", "range of validity"),
    ("card.name", ""),
    ("thermal.ambient_C", "operating condition"),
    ("material.elastic_modulus_Pa", "state it"),
    ("initial.s_mean_um", "measure it"),
    ("mill.vial_radius_m", "measure it"),
])
def test_params_refuses_what_is_not_a_model_constant_before_any_work(tmp_path, capsys, no_work, name, why):
    line = _refused(capsys, tmp_path, f"gamma,{name}")
    assert name in line and why in line and ALLOWED in line


@pytest.mark.parametrize("params, needle", [
    ("gama", "'gama': no such parameter (did you mean gamma?)"),
    ("stochastik.alpha", "(did you mean stochastic.alpha?)"),
    ("gamma,,delta", "an empty entry"),
    ("gamma,stochastic.gamma_per_um2", "named twice"),
])
def test_params_names_typos_empty_entries_and_aliases_named_twice(tmp_path, capsys, no_work, params, needle):
    assert needle in _refused(capsys, tmp_path, params)


def test_params_refuses_a_constant_that_is_zero_on_the_card_and_accepts_the_documented_ones(tmp_path):
    card = load_card(LAB)
    names = "alpha,beta,gamma,delta,material.bond_threshold_J_per_m,partition.max_strain,thermal.cooling_time_s"
    assert parse_params(names, card) == names.split(",")
    zero = card.model_copy(update={"partition": card.partition.model_copy(update={"equiaxing_efficiency": 0.0})})
    with pytest.raises(InputError, match=r"^names: partition.equiaxing_efficiency is 0 on the card"):
        parse_params("partition.equiaxing_efficiency", zero)


def test_run_calibration_refuses_a_setting_before_any_work(monkeypatch):
    def work(*a, **k):
        raise AssertionError("the calibration started")

    from bmctl.calibrate import moment_start

    monkeypatch.setattr(run_module, "calibrate", work)
    monkeypatch.setattr(moment_start, "moment_start", work)
    # from Python the message names the argument as run_calibration takes it
    with pytest.raises(InputError, match=r"^names: process.rpm is an operating setting"):
        run_module.run_calibration(load_card(LAB), LAB, [], ["gamma", "process.rpm"], None)


def test_a_mistyped_history_key_is_named_not_reported_missing(tmp_path):
    text = HISTORY.read_text(encoding="utf-8")
    p = tmp_path / "h.toml"
    p.write_text(text.replace("[[sample]]", "[[sampel]]", 1), encoding="utf-8")
    with pytest.raises(InputError, match=r"h.toml: sampel: unknown field \(did you mean sample\?\)$"):
        load_history(p)
    p.write_text(text.replace("rpm = 300", "rmp = 300", 1), encoding="utf-8")
    with pytest.raises(InputError, match=r"h.toml: segment\[0\]\.rmp: unknown field \(did you mean rpm\?\)$"):
        load_history(p)


def test_summary_gives_units_and_singular_counts(tmp_path, capsys, monkeypatch):
    cal = SimpleNamespace(names=["gamma", "alpha"], values=np.array([1.836e-4, 2.0]), lo90=np.array([1.6e-4, 1.5]),
                          hi90=np.array([2.1e-4, 2.6]), card_values=np.array([1.82e-4, 2.1]), identified=[True, False],
                          plant_runs=1, chi2=3.0, n_summaries=20, converged=True, stop_reason="")
    monkeypatch.setattr(run_module, "run_calibration",
                        lambda *a, **k: SimpleNamespace(calibration=cal, wall_s=1.0, paths=[], removed=[]))
    rc = main(["calibrate", str(LAB), str(HISTORY), "--params", "gamma,alpha", "--workers", "0",
               "--out", str(tmp_path / "out")])
    out = capsys.readouterr().out
    assert rc == 0
    assert ": 1 history, 5 samples; 1 plant run (serial)" in out
    assert "0.0001836 µm^-2  90 % [0.00016, 0.00021] µm^-2  x1.01 of the card" in out
    alpha = next(ln for ln in out.splitlines() if ln.strip().startswith("alpha"))
    assert "µm" not in alpha and "2  90 % [1.5, 2.6]  x0.95 of the card  NOT IDENTIFIED" in alpha


def test_bootstrap_of_a_large_sample_is_drawn_in_blocks_with_the_same_numbers(monkeypatch):
    """A measured sample of many particles is resampled in blocks: the covariance is the one of all
    resamples drawn at once (same stream), and the memory held does not grow as n_boot x n."""
    import tracemalloc

    from bmctl.calibrate import simulate

    rng = np.random.default_rng(4)
    n, n_boot = 20_001, 400
    s_um, r = np.exp(rng.normal(4.0, 0.5, n)), rng.uniform(0.0, 0.6, n)
    gen = np.random.default_rng(9)  # the reference: every resample's indices drawn at once
    idx = gen.integers(0, n, size=(n_boot, n))
    ls, rr = np.log(s_um)[idx], r[idx]
    want = np.cov(np.stack([ls.mean(1), ls.std(1), rr.mean(1), rr.std(1)], axis=1), rowvar=False)
    after = gen.integers(0, 1000, size=5)  # and the stream goes on where it would have
    del idx, ls, rr
    monkeypatch.setattr(simulate, "BOOT_BLOCK", 1 << 16, raising=False)
    gen = np.random.default_rng(9)
    tracemalloc.start()
    try:
        got = simulate.bootstrap_cov(s_um, r, gen, n_boot)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert np.array_equal(got, want)
    assert np.array_equal(gen.integers(0, 1000, size=5), after)
    assert peak < 8 * n_boot * n / 4, peak  # all at once: 3 x 8 bytes x n_boot x n (~190 MB)
