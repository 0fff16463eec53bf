import os
from pathlib import Path

import pytest

# before any fixture (module-scoped ones included) builds an MPC: interpreted, no gcc, no cache writes
os.environ["BMCTL_MPC_COMPILE"] = "0"

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT / "models"
CARDS = ["alni-1to1-300rpm-lab", "alni-1to1-400rpm-fan", "alni-1to3-300rpm-hadjiafxenti"]


@pytest.fixture(scope="session")
def root():
    return ROOT


def card_path(name: str) -> Path:
    return MODELS / f"{name}.toml"


@pytest.fixture(autouse=True)
def _interpreted_mpc(monkeypatch):
    """Tests run the MPC interpreted (no background gcc, no writes to the user's cache);
    tests/test_mpc_cache.py turns compilation on where it tests it."""
    monkeypatch.setenv("BMCTL_MPC_COMPILE", "0")
