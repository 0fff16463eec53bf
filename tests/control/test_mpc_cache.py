"""Compiled MPC solvers: the cache key, a corrupt library, and compiled == interpreted plans."""

import functools
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from bmctl.control import cache, make_controller
from bmctl.control.config import load_controller
from bmctl.moments.model import make_moment_model

from tests.conftest import ROOT, TEST_CFLAGS, card_path


@pytest.fixture
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    # gcc -O0 (the cold exact-Hessian NLP: ~36 s vs ~3 min); what the tests check (same plans, keys,
    # loading) does not depend on the optimisation level
    monkeypatch.setattr(cache, "CFLAGS", TEST_CFLAGS)
    return tmp_path / "xdg" / "bmctl" / "mpc"


def _controller(model, hours=4.0, tight=False, horizon=None):
    cfg = load_controller(ROOT / "controllers" / "mpc-default.toml")
    cfg = cfg.model_copy(update={"batch_hours": hours, "plan": cfg.plan.model_copy(update={"method": "nlp"})})
    if horizon is not None:
        cfg = cfg.model_copy(update={"horizon": horizon})
    if tight:  # converged solves (the shipped tolerances stop at "acceptable" iterates a few rpm apart)
        cfg = cfg.model_copy(update={"solver": cfg.solver.model_copy(update={
            "tol": 1e-8, "acceptable_tol": 1e-7, "acceptable_iter": 5, "max_iter": 400})})
    X = model.simulate(model.x0(), [[350.0, 0.8]] * 8, 0.5)
    return make_controller(cfg, model, {"s_mean_um": float(X[-1, 0]), "r_mean": float(X[-1, 2])})


def _library(ctrl):
    ctrl._build()
    return ctrl._library(("warm", "limited-memory"), {"ipopt.max_iter": 100})


def test_cache_key_changes_with_the_coefficients(private_cache):
    model = make_moment_model(card_path("alni-1to1-300rpm-lab"))
    a = _library(_controller(model))
    assert a == _library(_controller(model))  # same NLP, same file
    assert a.parent == private_cache
    key = next(k for k, v in model.coeffs.items() if isinstance(v, float) and v != 0.0)
    other = make_moment_model(card_path("alni-1to1-300rpm-lab"), coeffs={**model.coeffs, key: model.coeffs[key] * 1.01})
    assert _library(_controller(other)) != a


def test_cache_key_is_of_the_nlp_inputs_and_builds_nothing(private_cache):
    """The library's key follows what enters the NLP (a weight) and not a constraint bound (the
    ceiling); computing it builds no NLP."""
    model = make_moment_model(card_path("alni-1to1-300rpm-lab"))
    ctrl = _controller(model)
    warm = ("warm", "limited-memory"), {"ipopt.max_iter": 100}
    a = ctrl._library(*warm)
    assert ctrl._nlp is None and ctrl._nlp_c is None
    cfg = ctrl.cfg
    hot = cfg.model_copy(update={"temperature": cfg.temperature.model_copy(update={"ceiling_c": 55.0})})
    heavy = cfg.model_copy(update={"weights": cfg.weights.model_copy(update={"energy_per_kWh": 0.7})})
    assert make_controller(hot, model, ctrl.reference)._library(*warm) == a
    assert make_controller(heavy, model, ctrl.reference)._library(*warm) != a
    assert ctrl._library(("cold", "limited-memory"), {"ipopt.max_iter": 100}) != a
    ctrl._build()  # the layout _sizes() computes without building is the built NLP's (asserted there)
    assert ctrl._library(*warm) == a


def test_corrupt_library_is_ignored_and_removed(private_cache, capsys):
    private_cache.mkdir(parents=True)
    bad = private_cache / "mpc-warm-0123456789abcdef01234567.so"
    bad.write_bytes(b"not a shared library")
    assert cache.load(bad, "mpc_warm", {"print_time": False}) is None
    assert not bad.exists()  # the next process rebuilds it
    assert "did not load" in capsys.readouterr().err


def test_a_shared_cache_folder_is_refused(private_cache):
    private_cache.mkdir(parents=True)
    os.chmod(private_cache, 0o777)
    assert cache.cache_dir() is None


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")
def test_compiled_and_interpreted_solvers_give_the_same_plans(private_cache, monkeypatch):
    """A 4-interval horizon (the shipped 8 generates, compiles and solves the same NLP at twice the size:
    ~100 s here instead of ~40 s); 5 receding steps of a 4 h batch, then a fresh and a cold controller."""
    model = make_moment_model(card_path("alni-1to1-300rpm-lab"))
    ctl = functools.partial(_controller, model, tight=True, horizon=4)
    plans = {}
    for mode in ("0", "wait"):
        monkeypatch.setenv(cache.ENV_SWITCH, mode)
        ctrl = ctl()
        x, u, out = model.x0(), None, []
        for k in range(5):
            if k == 3:
                state, x3, u3 = ctrl.get_state(), x.copy(), u
            plan = ctrl.plan(x, 0.5 * k, None, u)
            assert plan.status.success
            out.append(plan.u)
            u = plan.u_apply
            x = model.step(x, u, 0.5)
        plans[mode] = np.array(out)
    assert any(private_cache.glob("mpc-warm-*.so")) and any(private_cache.glob("mpc-cold-*.so"))
    # a controller that finds the compiled library (as a fresh process does) builds no NLP and plans alike
    fresh = ctl()
    fresh.set_state(state)
    plan = fresh.plan(x3, 1.5, None, u3)
    assert plan.status.success and fresh._nlp is None and fresh._nlp_c is None
    np.testing.assert_allclose(plan.u, plans["wait"][3], rtol=1e-9)
    # the cold (exact-Hessian) solve from the library, in a controller that builds nothing symbolic
    cold = ctl()
    first = cold.plan(model.x0(), 0.0, None, None)
    assert first.status.success and cold._nlp is None and cold._nlp_c is None
    np.testing.assert_allclose(first.u, plans["wait"][0], rtol=1e-9)
    # converged to IPOPT tol 1e-8 (scaled): rpm within 0.1, milling fraction within 1e-3
    np.testing.assert_allclose(plans["wait"][..., 0], plans["0"][..., 0], atol=0.1)
    np.testing.assert_allclose(plans["wait"][..., 1], plans["0"][..., 1], atol=1e-3)


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")
def test_design_on_the_compiled_step_gives_the_interpreted_design(private_cache, monkeypatch):
    """bmctl design's moment step compiled with its reverse derivative (bmctl.control.pattern._design_step)
    solves the same pattern problem as casadi's interpreter: same integers, duties to solver tolerance."""
    from bmctl.control.compiled import _LOADED
    from bmctl.control.pattern import PatternDesigner

    cfg = load_controller(ROOT / "controllers" / "mpc-default.toml")
    target = {"d50_um": (40.0, 50.0)}
    res = {}
    for mode in ("0", "wait"):
        monkeypatch.setenv(cache.ENV_SWITCH, mode)
        model = make_moment_model(card_path("alni-1to1-300rpm-lab"))  # fresh: no step loaded before
        d = PatternDesigner(model, 4.0, cfg, target)
        loaded = [k for k in _LOADED.get(model, {}) if k[2]]  # (dt_h, substeps, reverse)
        assert loaded == ([] if mode == "0" else [(0.5, cfg.solver.substeps, True)])
        res[mode] = d.solve()
    assert any(private_cache.glob("band-*.so"))
    a, b = res["0"], res["wait"]
    assert a.segments == b.segments
    np.testing.assert_array_equal(a.rpm, b.rpm)
    np.testing.assert_array_equal(a.cycles, b.cycles)
    np.testing.assert_allclose(a.duty, b.duty, atol=1e-4)
    assert b.cost == pytest.approx(a.cost, rel=1e-4)


@pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")
def test_one_compile_per_library_across_processes(private_cache, monkeypatch):
    """A fresh lock file (another process compiling) means no second gcc; a stale one is replaced;
    the compile removes its lock when gcc ends."""
    import time

    import casadi as ca

    from bmctl.control.compiled import _Generator

    monkeypatch.setenv(cache.ENV_SWITCH, "1")
    x = ca.SX.sym("x")
    gen = _Generator(ca.Function("band_step", [x], [x * x]))
    path = cache.library_path("0" * 24, prefix="test")
    lock = path.with_name(path.name + ".lock")
    lock.write_text("12345", encoding="utf-8")
    cache.start_compile(gen, path)  # held by "another process": nothing started
    assert str(path) not in cache._running and not path.exists()
    old = time.time() - cache.LOCK_STALE_S - 60
    os.utime(lock, (old, old))  # left by a killed process
    cache.start_compile(gen, path, wait=True)
    assert path.is_file() and not lock.exists()


def test_generated_source_names_are_c_identifiers(tmp_path):
    """casadi takes the generated file's stem as a C identifier and refuses '__' (tempfile.mkstemp's
    random part can produce one): the cache's own names never hold it."""
    import re

    for _ in range(500):
        stem = Path(cache._new_source_file(tmp_path / "mpc-cold-0123abcd.so")).stem
        assert "__" not in stem and re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", stem)


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")
def test_the_gauss_newton_warm_solver_loads_from_its_library(private_cache, monkeypatch):
    """The Gauss-Newton Hessian is an nlpsol option (``hess_lag``), which ``generate_dependencies``
    leaves out: its library lacked ``nlp_hess_l``, did not load ("Derivatives cannot be calculated
    for nlp"), was removed and compiled again by every process, and the warm solver always ran
    interpreted. A fresh controller now plans from the library without building the NLP."""
    model = make_moment_model(card_path("alni-1to1-300rpm-lab"))

    def ctl():
        c = _controller(model, tight=True, horizon=4)
        c.cfg = c.cfg.model_copy(update={"solver": c.cfg.solver.model_copy(update={
            "hessian": "gauss-newton", "retry_exact": False})})
        return c

    monkeypatch.setenv(cache.ENV_SWITCH, "wait")
    ctrl = ctl()
    x, u = model.x0(), None
    for k in range(2):
        if k == 1:
            state, x1, u1 = ctrl.get_state(), x.copy(), u
        plan = ctrl.plan(x, 0.5 * k, None, u)
        u = plan.u_apply
        x = model.step(x, u, 0.5)
    fresh = ctl()
    fresh.set_state(state)
    again = fresh.plan(x1, 0.5, None, u1)
    assert fresh._nlp is None and fresh._nlp_c is None  # the warm solve came from the library
    np.testing.assert_allclose(again.u, plan.u, rtol=1e-9)
    # the interpreted solver of the library's NLP (a process before gcc is done) takes the same iterates
    interp = ctl()
    monkeypatch.setattr(type(interp), "_compiled_solver", lambda self, key, opts: None)
    interp.set_state(state)
    np.testing.assert_array_equal(interp.plan(x1, 0.5, None, u1).u, again.u)
