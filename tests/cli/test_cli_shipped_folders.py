"""The shipped model cards and controller settings reach every installation: a clone reads them
beside the package, a wheel (``pip install .``, ``pip install git+...``) carries copies inside it
(``bmctl/_shipped/``). ``bmctl design`` and ``bmctl campaign init`` without ``--controller`` and
``bmctl verify`` without ``--models`` read them; an installation with neither says what is missing
in one line, exit 2."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from bmctl.cli import main

ROOT = Path(__file__).resolve().parents[2]
CARD = ROOT / "models" / "alni-1to1-300rpm-lab.toml"
FOLDERS = ("models", "controllers")
#: the shipped cards' names (their NAME.moments.toml companions left out)
CARDS = sorted(p.name for p in (ROOT / "models").glob("*.toml") if p.suffixes == [".toml"])


def _install(monkeypatch, tmp_path, packaged: bool) -> Path:
    """Point bmctl.shipped at a fake site-packages: no clone beside the package, and the shipped
    folders inside it (a wheel) or not (a package copied without them)."""
    import bmctl.shipped as S

    site = tmp_path / "site-packages"
    (site / "bmctl").mkdir(parents=True)
    if packaged:
        for folder in FOLDERS:
            shutil.copytree(ROOT / folder, site / "bmctl" / "_shipped" / folder)
    monkeypatch.setattr(S, "REPOSITORY", site)
    monkeypatch.setattr(S, "PACKAGED", site / "bmctl" / "_shipped")
    monkeypatch.chdir(tmp_path)  # no controllers/ in the working folder either
    return site


@pytest.mark.parametrize("argv, flag, folder", [
    (["design", str(CARD), "--target", "s_mean_um=35", "--plant-seeds", "0", "--out", "o"], "--controller",
     "controllers"),
    (["verify", "--quick", "--out", "o"], "--models", "models"),
    (["campaign", "init", "o", "--model", str(CARD), "--target", "s_mean_um=45", "--hours", "2"], "--controller",
     "controllers"),
])
def test_an_installation_without_the_shipped_folders_names_what_is_missing(tmp_path, monkeypatch, capsys,
                                                                            argv, flag, folder):
    site = _install(monkeypatch, tmp_path, packaged=False)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0]
    assert err[0].startswith(f"bmctl: error: {flag}: not given") and f"no shipped {folder}/ folder" in err[0]
    assert "pip install" in err[0]
    assert not (site.parent / "o").exists()  # nothing written


def test_a_wheel_reads_the_copies_it_carries(tmp_path, monkeypatch):
    from bmctl.commands import design, verify
    from bmctl.shipped import shipped_dir

    site = _install(monkeypatch, tmp_path, packaged=True)
    for folder in FOLDERS:
        assert shipped_dir(folder) == site / "bmctl" / "_shipped" / folder
    assert design.controller_path(None) == site / "bmctl" / "_shipped" / "controllers" / "mpc-default.toml"
    (tmp_path / "controllers").mkdir()  # a copy of one's own in the working folder comes first
    shutil.copy2(ROOT / "controllers" / "mpc-default.toml", tmp_path / "controllers" / "mpc-default.toml")
    assert design.controller_path(None) == Path("controllers/mpc-default.toml")
    cards = verify.default_cards()
    assert sorted(p.name for p in cards) == CARDS
    assert all(p.parent == site / "bmctl" / "_shipped" / "models" for p in cards)


def test_shipped_folders_resolve_from_a_clone():
    from bmctl.commands._args import shipped

    assert shipped("controllers", "--controller") == ROOT / "controllers"
    assert (shipped("models", "--models") / "alni-1to1-300rpm-lab.toml").is_file()


@pytest.mark.slow
def test_the_built_wheel_carries_every_shipped_card_and_controller(tmp_path):
    """Build the wheel as pip does (isolated build, from a copy of the sources: pip builds in the
    source tree), install it without dependencies into a folder of its own, and read the shipped
    defaults from there, away from the clone."""
    src = tmp_path / "src"
    skip = shutil.ignore_patterns("__pycache__", "*.pyc")
    for folder in ("bmctl", *FOLDERS):
        shutil.copytree(ROOT / folder, src / folder, ignore=skip)
    for name in ("setup.py", "pyproject.toml", "README.md"):
        shutil.copy2(ROOT / name, src / name)
    build = subprocess.run([sys.executable, "-m", "pip", "wheel", str(src), "--no-deps", "-q", "-w", str(tmp_path)],
                           capture_output=True, text=True)
    assert build.returncode == 0, build.stderr[-2000:]
    (wheel,) = tmp_path.glob("bmctl-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    for folder in FOLDERS:
        for p in (ROOT / folder).glob("*.toml"):
            assert f"bmctl/_shipped/{folder}/{p.name}" in names, f"{folder}/{p.name} is not in the wheel"
    target = tmp_path / "site"
    with zipfile.ZipFile(wheel) as z:
        z.extractall(target)  # a wheel's files install as they are stored (no scripts or data here)
    probe = ("import bmctl, bmctl.shipped as S; from bmctl.commands import design, verify; "
             "from bmctl.plant.plant import default_card; "
             "print(bmctl.__file__); print(design.controller_path(None)); print(len(verify.default_cards())); "
             "print(default_card().card.name)")
    env = {**os.environ, "PYTHONPATH": str(target)}
    run = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, cwd=tmp_path, env=env)
    assert run.returncode == 0, run.stderr[-2000:]
    module, controller, cards, card_name = run.stdout.split("\n")[:4]
    assert Path(module).is_relative_to(target)
    assert Path(controller) == target / "bmctl" / "_shipped" / "controllers" / "mpc-default.toml"
    assert int(cards) == len(CARDS)
    assert card_name  # the lab card loads from the copy


def test_campaign_init_without_a_controller_starts_with_the_shipped_mpc(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)  # no controllers/ here: the shipped one
    assert main(["campaign", "init", "c", "--model", str(CARD), "--target", "s_mean_um=45", "--hours", "2"]) == 0
    copied = tmp_path / "c" / "inputs" / "controller-mpc-default.toml"
    assert copied.read_bytes() == (ROOT / "controllers" / "mpc-default.toml").read_bytes()
    assert "controller mpc" in capsys.readouterr().out


def test_a_folder_beside_an_installed_package_is_not_taken_for_the_shipped_one(tmp_path, monkeypatch):
    """site-packages may hold another distribution's top-level ``models`` or ``controllers`` package:
    only a clone (bmctl's pyproject.toml above the package) or the wheel's own copy counts."""
    from bmctl.shipped import shipped_dir

    site = _install(monkeypatch, tmp_path, packaged=False)
    (site / "models").mkdir()  # e.g. a package named "models" installed beside bmctl
    (site / "models" / "__init__.py").write_text("", encoding="utf-8")
    assert shipped_dir("models") is None
    (site / "pyproject.toml").write_text("[project]\nname = 'bmctl'\n", encoding="utf-8")  # a clone
    assert shipped_dir("models") == site / "models"
    for folder in FOLDERS:  # the wheel's own copy first
        shutil.copytree(ROOT / folder, site / "bmctl" / "_shipped" / folder)
    assert shipped_dir("models") == site / "bmctl" / "_shipped" / "models"
