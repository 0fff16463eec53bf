from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT / "models"
CARDS = ["alni-1to1-300rpm-lab", "alni-1to1-400rpm-fan", "alni-1to3-300rpm-hadjiafxenti"]


@pytest.fixture(scope="session")
def root():
    return ROOT


def card_path(name: str) -> Path:
    return MODELS / f"{name}.toml"
