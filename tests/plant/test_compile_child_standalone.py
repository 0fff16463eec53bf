"""The background compile of the plant's compiled engine works from an installed package (no ``models/``
next to it), and a compile that fails says so once and is not retried for the same install."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("numba")

from bmctl.plant import _compiled as cc  # noqa: E402

PACKAGE = Path(cc.__file__).resolve().parents[1]


def _env(tmp_path: Path, site: Path) -> dict:
    env = dict(os.environ)
    env.pop("BMCTL_COMPILE", None)
    env.update(PYTHONPATH=str(site), NUMBA_CACHE_DIR=str(tmp_path / "numba"), XDG_CACHE_HOME=str(tmp_path / "xdg"))
    return env


@pytest.mark.slow
def test_background_compile_runs_from_a_package_without_the_models_folder(tmp_path):
    # the package alone, as a wheel installs it: no models/ beside it, no compiled cache
    site = tmp_path / "site"
    shutil.copytree(PACKAGE, site / "bmctl", ignore=shutil.ignore_patterns("__pycache__"))
    assert not (site / "models").exists()
    env = _env(tmp_path, site)
    lock = tmp_path / "compile.lock"
    lock.touch()
    child = subprocess.run([sys.executable, "-m", "bmctl.plant._compiled", str(lock)], cwd=site, env=env,
                           capture_output=True, text=True, timeout=600)
    assert child.returncode == 0, child.stderr[-2000:]
    assert not lock.exists()
    probe = ("from bmctl.plant import _compiled as cc; "
             "print(cc.__file__); print(cc.cache_is_warm()); print(cc.compile_failure())")
    out = subprocess.run([sys.executable, "-c", probe], cwd=tmp_path, env=env, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    where, warm, failure = out.stdout.split("\n")[:3]
    assert Path(where).resolve().is_relative_to(site.resolve())
    assert (warm, failure) == ("True", "None")


def test_failed_compile_is_recorded_noted_once_and_not_retried(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.setattr(cc, "_lock_path", lambda: str(tmp_path / "compile.lock"))
    monkeypatch.setattr(cc, "_NOTED", {"failure": False})
    started = []
    monkeypatch.setattr(subprocess, "Popen", lambda *a, **k: started.append(a))

    def broken():
        raise ValueError("no card")

    monkeypatch.setattr(cc, "compile_now", broken)
    lock = tmp_path / "compile.lock"
    lock.touch()
    assert cc._main([str(lock)]) == 1  # the background child: exit status, error kept, lock released
    assert not lock.exists()
    assert cc.compile_failure() == "ValueError: no card"
    assert Path(cc.failure_path()).parent == tmp_path / "xdg" / "bmctl"

    assert cc.compile_in_background() is False and cc.compile_in_background() is False
    assert started == [] and not lock.exists()
    err = capsys.readouterr().err
    assert err.count("bmctl: note:") == 1 and "ValueError: no card" in err and cc.failure_path() in err

    # a foreground compile that succeeds clears the record: background compiles start again
    monkeypatch.setattr(cc, "compile_now", lambda: None)
    monkeypatch.setattr(cc, "cache_is_warm", lambda: True)
    assert cc._main([]) == 0
    assert cc.compile_failure() is None
    assert cc.compile_in_background() is True and len(started) == 1
    assert lock.exists()  # held for the child it started


def test_a_compile_that_leaves_the_cache_cold_is_a_failure(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.setattr(cc, "compile_now", lambda: None)
    monkeypatch.setattr(cc, "cache_is_warm", lambda: False)
    assert cc._main([str(tmp_path / "no-lock")]) == 1
    assert "cache stayed cold" in cc.compile_failure()
