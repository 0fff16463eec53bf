"""Every docstring example in the package runs (``# doctest: +SKIP`` only where a figure is drawn
or a long run is shown). Only modules that hold examples are collected: a module without one
would pass on import and prove nothing. Key public entry points must carry a runnable example."""

import doctest
import importlib
import inspect
import pkgutil
from pathlib import Path

import pytest

import bmctl

from .conftest import ROOT


def _has_examples(info) -> bool:
    spec = importlib.util.find_spec(info.name)
    origin = Path(spec.origin) if spec and spec.origin else None
    return origin is not None and origin.suffix == ".py" and ">>> " in origin.read_text(encoding="utf-8")


MODULES = sorted(m.name for m in pkgutil.walk_packages(bmctl.__path__, "bmctl.")
                 if not m.name.endswith("__main__") and _has_examples(m))

#: modules whose examples take over a second (run the model, the filter or draw): full run only
SLOW = {"bmctl.moments.model", "bmctl.estimate.ukf", "bmctl.plots", "bmctl.simulate", "bmctl.measure.segment",
        "bmctl.plant._compiled", "bmctl.trial", "bmctl.whatif"}

#: public entry points a user calls first; each must show a runnable (not skipped) example
KEY_API = ["bmctl.config:load_card", "bmctl.plant.plant:Plant", "bmctl.plant.plant:make_plant",
           "bmctl.simulate:simulate", "bmctl.moments.model:make_moment_model", "bmctl.estimate.filter:ParticleFilter",
           "bmctl.control:make_controller", "bmctl.trial:run_trial", "bmctl.whatif:run_schedule_ensemble",
           "bmctl.schedule:Schedule", "bmctl.stats:size_stats", "bmctl.results:write_results",
           "bmctl.parallel:ensemble_map", "bmctl.measure.tables:read_table"]


@pytest.mark.parametrize("name", [pytest.param(m, marks=pytest.mark.slow) if m in SLOW else m for m in MODULES])
def test_docstring_examples(name, monkeypatch):
    monkeypatch.chdir(ROOT)  # examples name the shipped files by their repository paths
    mod = importlib.import_module(name)
    res = doctest.testmod(mod, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE, verbose=False)
    assert res.attempted > 0, f"{name}: no example ran (all skipped?)"
    assert res.failed == 0, f"{name}: {res.failed} of {res.attempted} examples failed"


@pytest.mark.parametrize("spec", KEY_API)
def test_key_public_api_has_a_runnable_example(spec):
    modname, attr = spec.split(":")
    obj = getattr(importlib.import_module(modname), attr)
    examples = doctest.DocTestParser().get_examples(inspect.getdoc(obj) or "")
    runnable = [e for e in examples if not e.options.get(doctest.SKIP)]
    assert runnable, f"{spec}: no runnable example in its docstring"
