"""A non-editable install (``pip install .``, a wheel) has no models/ or controllers/ beside the
package: ``bmctl design`` without ``--controller`` said "file not found" for a path inside
site-packages, and ``bmctl verify`` "none found in .../models". Each now says what is missing and
what to do, in one line, exit 2; from a clone the defaults still resolve from any folder."""

from __future__ import annotations

from pathlib import Path

import pytest

from bmctl.cli import main

ROOT = Path(__file__).resolve().parents[2]
CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"


@pytest.fixture
def installed_without_clone(tmp_path, monkeypatch):
    import bmctl.commands._args as args

    fake = tmp_path / "site-packages"
    (fake / "bmctl").mkdir(parents=True)
    monkeypatch.setattr(args, "REPOSITORY", fake)
    monkeypatch.chdir(tmp_path)  # no controllers/ in the working folder either
    return fake


@pytest.mark.parametrize("argv, flag, folder", [
    (["design", str(CARD), "--target", "s_mean_um=35", "--plant-seeds", "0"], "--controller", "controllers"),
    (["verify", "--quick"], "--models", "models"),
])
def test_defaults_of_a_non_editable_install_name_what_is_missing(installed_without_clone, capsys, argv, flag, folder):
    out = installed_without_clone
    assert main(argv + ["--out", str(out.parent / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0]
    assert err[0].startswith(f"bmctl: error: {flag}: not given") and f"no {folder}/ folder" in err[0]
    assert "pip install -e ." in err[0]
    assert not (out.parent / "o").exists()  # nothing written


def test_shipped_folders_resolve_from_a_clone():
    from bmctl.commands._args import shipped

    assert shipped("controllers", "--controller") == ROOT / "controllers"
    assert (shipped("models", "--models") / "alni-1to1-300rpm-lab.toml").is_file()
