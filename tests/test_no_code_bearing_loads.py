"""No code in the package or the benchmarks unpickles, evals or yaml-loads a file: a folder the user
points at may hold anything (the project's rule: never load code-bearing formats from it)."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FORBIDDEN = re.compile(r"^\s*(import pickle|from pickle import|import joblib|import dill|import cloudpickle)"
                       r"|pickle\.loads?\(|joblib\.load\(|yaml\.load\(|allow_pickle\s*=\s*True|\beval\(|\bexec\(",
                       re.MULTILINE)


@pytest.mark.parametrize("folder", ["bmctl", "benchmarks"])
def test_no_code_bearing_format_is_loaded(folder):
    hits = [f"{p.relative_to(ROOT)}: {m.group(0).strip()}" for p in sorted((ROOT / folder).rglob("*.py"))
            for m in FORBIDDEN.finditer(p.read_text(encoding="utf-8"))]
    assert not hits, hits
