"""Ctrl-C during a CasADi solve stops the run (CasADi catches the KeyboardInterrupt and ends the
solve as a failure; the trial then fell back and carried on, exit 0, another result)."""

import signal

import pytest

from bmctl.control.interrupt import keep_interrupts


@pytest.fixture(autouse=True)
def python_sigint():
    """Python's own SIGINT handler for each test, whatever the test runner's worker left (an xdist
    worker may ignore SIGINT, or inherit what an earlier test set); put back afterwards."""
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, old)


def test_an_interrupt_the_solver_swallows_is_raised_after_it():
    with pytest.raises(KeyboardInterrupt):
        with keep_interrupts():
            try:  # what CasADi does with Ctrl-C inside IPOPT
                signal.raise_signal(signal.SIGINT)
            except KeyboardInterrupt:
                pass
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # put back


def test_a_block_without_an_interrupt_runs_as_it_is():
    with keep_interrupts():
        x = 1
    assert x == 1 and signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_the_nlp_solve_raises_the_interrupt(monkeypatch):
    """The MPC's solve: a solver that swallows Ctrl-C (as IPOPT through CasADi) ends in KeyboardInterrupt."""
    from pathlib import Path

    from bmctl.control import make_controller
    from bmctl.control.config import load_controller
    from bmctl.moments.model import make_moment_model

    root = Path(__file__).resolve().parents[2]
    model = make_moment_model(root / "models" / "alni-1to1-300rpm-lab.toml")
    ctrl = make_controller(load_controller(root / "controllers" / "mpc-nominal.toml"), model, {"s_mean_um": 30.0})
    real = ctrl._solver

    def swallowing(*a, **k):
        solver = real(*a, **k)

        class Wrapped:
            def __call__(self, **kw):
                try:
                    signal.raise_signal(signal.SIGINT)
                except KeyboardInterrupt:
                    pass
                return solver(**kw)

            def stats(self):
                return solver.stats()

        return Wrapped()

    monkeypatch.setattr(ctrl, "_solver", swallowing)
    with pytest.raises(KeyboardInterrupt):
        ctrl.plan(model.x0(), 0.0)
