"""Compiled MPC solvers, cached on disk and shared by every process.

The MPC's NLP (:mod:`bmctl.control.mpc`) is generated as C by casadi
(``nlpsol(...).generate_dependencies``), compiled by ``gcc`` into a shared library and loaded
with ``casadi.nlpsol(name, "ipopt", "<lib>.so", opts)``. IPOPT then evaluates the objective,
constraints and their derivatives in machine code instead of casadi's interpreter.

Decisions
---------
* **Key.** The file name carries a SHA-256 of the serialized NLP function (``f``, ``g`` and,
  when given, the Gauss-Newton Hessian) -- so the model card, the identified coefficients,
  the horizon, the interval, the weights and the equations' code are all in it -- plus the
  casadi version, the solver kind and the compiler flags. Anything that changes the NLP
  changes the key; nothing is ever invalidated by hand.
* **Where.** Only bmctl's own cache folder, ``$XDG_CACHE_HOME/bmctl/mpc`` (default
  ``~/.cache/bmctl/mpc``), created with mode 0700. A folder owned by another user or writable
  by others is refused (compiled code is code). No path given by the user is ever loaded.
* **Atomic.** gcc writes a temporary file in the same folder, renamed into place when it
  succeeded, so a reader never loads a half-written library.
* **In the background.** The first process that needs a library starts gcc in the background
  and keeps using the interpreted solver; the compiled one is picked up at the next solve after
  gcc finished (in this or any later process). A first run is therefore never slower than
  without compilation.
* **Fallbacks.** No gcc, a failed compile, or a library that does not load (corrupt,
  truncated): one line on stderr, the interpreted solver, and (for a bad file) the file is
  removed so the next process rebuilds it.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import stat
import subprocess
import sys
import tempfile
from pathlib import Path

#: gcc flags; part of the key
CFLAGS = ("-O1", "-fPIC", "-shared")
#: "0": casadi's interpreter only (no compilation, no cache); "wait": compile in the foreground
#: (benchmarks, tests); anything else: compile in the background
ENV_SWITCH = "BMCTL_MPC_COMPILE"

_notices: set[str] = set()
_running: dict[str, subprocess.Popen] = {}


def notice(text: str) -> None:
    """Print a one-line notice on stderr once per process."""
    if text not in _notices:
        _notices.add(text)
        print(f"bmctl: note: {text}", file=sys.stderr)


def wait_for_compile() -> bool:
    """Whether compiles block (``$BMCTL_MPC_COMPILE=wait``)."""
    return os.environ.get(ENV_SWITCH, "1") == "wait"


def enabled() -> bool:
    """Whether compiled solvers are used (``$BMCTL_MPC_COMPILE`` is not "0" and gcc is on PATH)."""
    if os.environ.get(ENV_SWITCH, "1") == "0":
        return False
    if shutil.which("gcc") is None:
        notice("gcc not found: the MPC runs on casadi's interpreter (slower solves)")
        return False
    return True


def cache_dir() -> Path | None:
    """bmctl's own cache folder for compiled solvers, created 0700; None when it is unsafe or unwritable.

    ``$XDG_CACHE_HOME/bmctl/mpc``, or ``~/.cache/bmctl/mpc`` when that variable is unset.
    """
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    d = Path(base) / "bmctl" / "mpc"
    try:
        d.mkdir(parents=True, exist_ok=True, mode=0o700)
        st = d.stat()
    except OSError as exc:
        notice(f"cache folder {d}: {exc.strerror or exc}: compiled MPC solvers are not cached")
        return None
    if st.st_uid != os.getuid() or st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        notice(f"cache folder {d} is not private to this user: compiled MPC solvers are not used")
        return None
    return d


def solver_key(functions, kind: str) -> str:
    """SHA-256 (hex, 24 characters) of the NLP's functions, the solver kind, casadi's version and the flags.

    Parameters
    ----------
    functions : list of casadi.Function
        Everything that defines the compiled code (the NLP ``f, g``; the Gauss-Newton Hessian).
    kind : str
        What is generated (e.g. ``"warm-limited-memory"``).
    """
    import casadi as ca

    h = hashlib.sha256()
    for part in (ca.__version__, kind, " ".join(CFLAGS)):
        h.update(part.encode() + b"\0")
    for f in functions:
        h.update(f.serialize().encode() + b"\0")
    return h.hexdigest()[:24]


def library_path(key: str, prefix: str = "mpc") -> Path | None:
    """Path of the compiled library for ``key`` in the cache folder (it may not exist yet)."""
    d = cache_dir()
    return None if d is None else d / f"{prefix}-{key}.so"


def ready(path: Path) -> bool:
    """True when the library exists (and no compile of it is still running in this process)."""
    proc = _running.get(str(path))
    if proc is not None:
        if proc.poll() is None:
            return False
        _running.pop(str(path), None)
        if proc.returncode != 0:
            notice(f"compiling {path.name} failed (gcc exit {proc.returncode}): the MPC stays interpreted")
    return path.is_file()


def start_compile(solver, path: Path, wait: bool = False) -> None:
    """Generate ``solver``'s C code and compile it into ``path`` (atomically), in the background.

    Parameters
    ----------
    solver : casadi.Function
        An ``nlpsol`` instance; its dependencies (f, g, derivatives) are generated.
    path : Path
        Destination library in :func:`cache_dir`.
    wait : bool, optional
        Block until gcc finished (tests, ``benchmarks/bench_control.py``).
    """
    if str(path) in _running or path.is_file():
        if wait and str(path) in _running:
            _running[str(path)].wait()
            ready(path)
        return
    fd, c_file = tempfile.mkstemp(prefix=f"gen_{path.stem.replace('-', '_')}_", suffix=".c", dir=path.parent)
    os.close(fd)
    tmp_so = c_file[:-2] + ".so"
    c_path = Path(c_file)
    cwd = os.getcwd()
    try:  # casadi writes the generated file into the working folder (it takes a bare name only)
        os.chdir(path.parent)
        solver.generate_dependencies(c_path.name, {"with_header": False})
    except Exception:
        c_path.unlink(missing_ok=True)
        raise
    finally:
        os.chdir(cwd)
    # compile to a temporary name, then rename into place; the sources are removed either way
    script = (f'gcc {" ".join(CFLAGS)} -o "{tmp_so}" "{c_file}" && mv -f "{tmp_so}" "{path}"; '
              f'rc=$?; rm -f "{c_file}" "{tmp_so}"; exit $rc')
    proc = subprocess.Popen(["sh", "-c", script], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    _running[str(path)] = proc
    if wait:
        proc.wait()
        ready(path)


def load(path: Path, name: str, opts: dict):
    """``casadi.nlpsol(name, "ipopt", path, opts)``, or None (the file is removed) when it does not load."""
    import casadi as ca

    try:
        return ca.nlpsol(name, "ipopt", str(path), opts)
    except Exception as exc:  # noqa: BLE001 - casadi raises RuntimeError on any bad library
        notice(f"compiled solver {path.name} did not load ({str(exc).splitlines()[0][:80]}): rebuilt")
        try:
            path.unlink()
        except OSError:
            pass
        return None
