import os
from pathlib import Path

import pytest

# before any fixture (module-scoped ones included) builds an MPC: interpreted, no gcc, no cache writes
os.environ["BMCTL_MPC_COMPILE"] = "0"

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT / "models"
CARDS = ["alni-1to1-300rpm-lab", "alni-1to1-400rpm-fan", "alni-1to3-300rpm-hadjiafxenti"]
#: gcc flags of the tests that compile the MPC: -O0 instead of the shipped -O1 (bmctl.control.cache.CFLAGS)
#: compiles in a fraction of the time; neither level reassociates or contracts floating point on x86-64
#: (no -ffast-math, no -march), so what the tests check does not depend on it
TEST_CFLAGS = ("-O0", "-fPIC", "-shared")


@pytest.fixture(scope="session")
def root():
    return ROOT


def card_path(name: str) -> Path:
    return MODELS / f"{name}.toml"


def load_benchmark(name: str):
    """The script ``benchmarks/<name>.py`` as a module (registered in ``sys.modules``, which the
    dataclasses of a script look their module up in)."""
    import importlib.util
    import sys

    spec = importlib.util.spec_from_file_location(f"benchmarks_{name}", ROOT / "benchmarks" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(autouse=True)
def _interpreted_mpc(monkeypatch):
    """Tests run the MPC interpreted (no background gcc, no writes to the user's cache);
    tests/test_mpc_cache.py turns compilation on where it tests it."""
    monkeypatch.setenv("BMCTL_MPC_COMPILE", "0")


#: the tests that run a minute or more on two cores: started first, so that no worker is left running one alone
#: at the end of `pytest -n auto`
LONG_FIRST = ("test_readme_commands_and_python_api_run_on_the_shipped_files",
              "test_trial_is_identical_with_cold_and_warm_compile_caches",
              "test_crash_mid_sample_leaves_a_consistent_campaign",
              "test_compiled_and_interpreted_solvers_give_the_same_plans")


def pytest_collection_modifyitems(config, items):
    """The long tests first, then the other tests of modules holding slow ones (each module's order kept), the
    many quick ones last: with `-n auto --dist worksteal` (pyproject.toml) the workers finish together."""
    def module(item):
        return getattr(getattr(item, "module", None), "__name__", "")

    slow = {module(item) for item in items if item.get_closest_marker("slow")}
    first = {name: k for k, name in enumerate(LONG_FIRST)}
    items.sort(key=lambda item: (first.get(item.name, len(first)), module(item) not in slow))
