"""Every docstring example in the package runs (``# doctest: +SKIP`` only where a figure is drawn
or a long run is shown)."""

import doctest
import importlib
import pkgutil

import pytest

import bmctl

from .conftest import ROOT

MODULES = sorted(m.name for m in pkgutil.walk_packages(bmctl.__path__, "bmctl.") if not m.name.endswith("__main__"))


#: modules whose examples take over a second (run the model, the filter or draw): full run only
SLOW = {"bmctl.moments.model", "bmctl.estimate.ukf", "bmctl.plots", "bmctl.simulate", "bmctl.measure.segment",
        "bmctl.plant._compiled"}


@pytest.mark.parametrize("name", [pytest.param(m, marks=pytest.mark.slow) if m in SLOW else m for m in MODULES])
def test_docstring_examples(name, monkeypatch):
    monkeypatch.chdir(ROOT)  # examples name the shipped files by their repository paths
    mod = importlib.import_module(name)
    res = doctest.testmod(mod, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE, verbose=False)
    assert res.failed == 0, f"{name}: {res.failed} of {res.attempted} examples failed"
