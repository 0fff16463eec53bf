"""No compile outlives its command: a background compile still running at exit is stopped and its
files removed (bmctl/control/cache.py: stop_running, registered with atexit)."""

from __future__ import annotations

import os
import stat
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest


def _fake_gcc(folder: Path) -> Path:
    """A 'gcc' that takes a minute: a compile that is still running when the command ends."""
    gcc = folder / "gcc"
    gcc.write_text("#!/bin/sh\nsleep 60\n", encoding="utf-8")
    gcc.chmod(gcc.stat().st_mode | stat.S_IXUSR)
    return folder


SCRIPT = textwrap.dedent("""
    import os, sys
    from pathlib import Path
    from bmctl.control import cache

    class Gen:
        def generate_dependencies(self, name, opts):
            Path(name).write_text("int f(void) { return 0; }\\n")

    path = cache.library_path("0" * 24, prefix="test")
    cache.start_compile(Gen(), path)
    proc = cache._running[str(path)]
    print(proc.pid, flush=True)
""")


@pytest.mark.parametrize("mode", ["1", "detach"])
def test_background_compile_is_stopped_at_exit_unless_detached(tmp_path, mode):
    (tmp_path / "bin").mkdir()
    fake = _fake_gcc(tmp_path / "bin")
    env = {**os.environ, "PATH": f"{fake}{os.pathsep}{os.environ['PATH']}",
           "XDG_CACHE_HOME": str(tmp_path / "cache"), "BMCTL_MPC_COMPILE": mode,
           "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    out = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    pgid = int(out.stdout.split()[0])
    cache = tmp_path / "cache" / "bmctl" / "mpc"
    alive = True
    for _ in range(50):  # killed members are reaped by init shortly after (zombies answer signal 0)
        try:
            os.killpg(pgid, 0)
        except ProcessLookupError:
            alive = False
            break
        if mode == "detach":
            break
        time.sleep(0.1)
    if mode == "detach":  # asked for: still running, its lock names it; stop it here
        assert alive
        (lock,) = cache.glob("*.lock")
        assert int(lock.read_text(encoding="utf-8")) == pgid
        os.killpg(pgid, 15)
    else:
        assert not alive
        assert "stopped 1 unfinished background compile" in out.stderr
        assert not list(cache.glob("*.lock")) and not list(cache.glob("gen_*.c"))
