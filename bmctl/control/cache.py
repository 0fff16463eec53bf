"""Compiled MPC solvers, cached on disk and shared by every process.

The MPC's NLP (:mod:`bmctl.control.mpc`) is generated as C by casadi
(``nlpsol(...).generate_dependencies``), compiled by ``gcc`` into a shared library and loaded
with ``casadi.nlpsol(name, "ipopt", "<lib>.so", opts)``. IPOPT then evaluates the objective,
constraints and their derivatives in machine code instead of casadi's interpreter.

Decisions
---------
* **Key.** The file name carries a SHA-256 of what the function is generated from
  (:func:`input_key`): the moment model's constants and identified coefficients, the controller
  settings that enter the NLP (horizon, interval, weights, slack weights, solver settings,
  adaptation, scenarios, whether D-values are targeted), the source of the modules that generate
  it, the casadi version, the solver kind and the compiler flags. Anything that changes the NLP
  changes the key; nothing is ever invalidated by hand. Keying by the inputs instead of by the
  built NLP lets a process that finds the library load it without building anything symbolic
  (~0.5 s CPU saved per fresh ``campaign advise``). A loaded library whose input and output
  sizes do not fit is removed and rebuilt.
* **Where.** Only bmctl's own cache folder, ``$XDG_CACHE_HOME/bmctl/mpc`` (default
  ``~/.cache/bmctl/mpc``), created with mode 0700. A folder owned by another user or writable
  by others is refused (compiled code is code). No path given by the user is ever loaded.
* **Atomic.** gcc writes a temporary file in the same folder, renamed into place when it
  succeeded, so a reader never loads a half-written library.
* **In the background, while the command runs.** The first process that needs a library starts gcc
  in the background and keeps using the interpreted solver; the compiled one is picked up at the
  next solve after gcc finished (in this or any later process). A first run is therefore never
  slower than without compilation. A compile still running when the command ends is stopped (its
  files and lock removed; one note on stderr): nothing of bmctl outlives its command. To compile
  anyway: ``BMCTL_MPC_COMPILE=wait`` compiles in the foreground, ``BMCTL_MPC_COMPILE=detach``
  leaves the compile running after the command (its lock file ``<name>.so.lock`` in the cache folder
  holds the compiler's process id: ``cat`` it to see, ``kill`` it to stop).
* **One compile per library.** A lock file next to the library (``<name>.so.lock``, created
  exclusively, removed by the compile's shell when gcc ends) keeps concurrent processes (trial
  workers, a second terminal) from compiling the same library twice; the others keep solving
  interpreted and load the library when it appears. A lock older than 30 min is taken as left
  by a killed process and replaced.
* **Fallbacks.** No gcc, a failed compile, or a library that does not load (corrupt,
  truncated): one line on stderr, the interpreted solver, and (for a bad file) the file is
  removed so the next process rebuilds it.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

#: gcc flags; part of the key
CFLAGS = ("-O1", "-fPIC", "-shared")
#: "0": casadi's interpreter only (no compilation, no cache); "wait": compile in the foreground
#: (benchmarks, tests); "detach": compile in the background and leave it running after the command;
#: anything else: compile in the background, stopped when the command ends
ENV_SWITCH = "BMCTL_MPC_COMPILE"

_notices: set[str] = set()
_running: dict[str, subprocess.Popen] = {}
_files: dict[str, tuple[str, ...]] = {}  # library path -> (generated C file, temporary library, lock)


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


#: modules whose code determines the generated functions; their bytes are part of :func:`input_key`
SOURCES = ("moments/equations.py", "moments/model.py", "moments/numerics.py", "moments/physics.py",
           "moments/coeffs.py", "stats.py", "physics/constants.py", "physics/thermal.py", "physics/impacts.py",
           "physics/kinematics.py", "control/mpc.py", "control/compiled.py", "control/outputs.py",
           "control/config.py", "control/base.py", "control/cache.py", "campaign/band.py")
#: version of the input-key layout
KEY_FORMAT = 1


@functools.lru_cache(maxsize=1)
def _sources_digest() -> bytes:
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for name in SOURCES:
        p = root / name
        h.update(name.encode() + b"\0" + (p.read_bytes() if p.exists() else b"-") + b"\0")
    return h.digest()


def _plain(v):
    """JSON form of numpy scalars, arrays and tuples inside key inputs."""
    if hasattr(v, "tolist"):
        return v.tolist()
    raise TypeError(f"not plain data in a cache key: {type(v).__name__}")


def model_inputs(model) -> dict:
    """What a moment model's casadi functions are built from: its constants and coefficients."""
    return {"const": model.const.as_dict(), "coeffs": dict(model.coeffs)}


def input_key(kind: str, inputs: dict) -> str:
    """SHA-256 (hex, 24 characters) of what a compiled function is generated from, without building it.

    The key covers the inputs (plain data: the model's constants and coefficients, the
    controller settings that enter the NLP, the interval and horizon), the source of the modules
    that generate the function (:data:`SOURCES`), casadi's version, the compiler flags and
    ``kind``. A cache hit therefore loads the library without building anything symbolic.

    Parameters
    ----------
    kind : str
        What is generated (e.g. ``"mpc-warm-gauss-newton-it12"``).
    inputs : dict
        Plain data (numbers, strings, lists, dicts; numpy values are converted).
    """
    import casadi as ca

    h = hashlib.sha256()
    for part in (f"bmctl-input-key-{KEY_FORMAT}", ca.__version__, kind, " ".join(CFLAGS)):
        h.update(part.encode() + b"\0")
    h.update(json.dumps(inputs, sort_keys=True, default=_plain).encode() + b"\0")
    h.update(_sources_digest())
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
    lock = _lock_path(path)
    if not _take_lock(lock):  # another process is compiling it: use its library when it is there
        if wait:
            _wait_for_other(path, lock)
        return
    c_file = _new_source_file(path)
    tmp_so = c_file[:-2] + ".so"
    c_path = Path(c_file)
    sources = [c_file]
    cwd = os.getcwd()
    try:  # casadi writes the generated file into the working folder (it takes a bare name only)
        os.chdir(path.parent)
        solver.generate_dependencies(c_path.name, {"with_header": False})
        _hessian_source(solver, c_path, path, sources)
    except Exception:
        for f in sources:
            Path(f).unlink(missing_ok=True)
        lock.unlink(missing_ok=True)
        raise
    finally:
        os.chdir(cwd)
    # compile to a temporary name, then rename into place; the sources are removed either way
    quoted = " ".join(f'"{f}"' for f in sources)
    script = (f'gcc {" ".join(CFLAGS)} -o "{tmp_so}" {quoted} && mv -f "{tmp_so}" "{path}"; '
              f'rc=$?; rm -f {quoted} "{tmp_so}" "{lock}"; exit $rc')
    proc = subprocess.Popen(["sh", "-c", script], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    _running[str(path)] = proc
    try:  # the lock names the compile's process (group): `cat` it to see, `kill` it to stop
        lock.write_text(str(proc.pid), encoding="utf-8")
    except OSError:
        pass
    if os.environ.get(ENV_SWITCH, "1") != "detach":
        _files[str(path)] = (*sources, tmp_so, str(lock))
        _register_stop()
    if wait:
        proc.wait()
        ready(path)


_stop_registered = False


def _register_stop() -> None:
    global _stop_registered
    if not _stop_registered:
        import atexit

        atexit.register(stop_running)
        _stop_registered = True


def stop_running() -> list[str]:
    """Stop the background compiles this process started that are still running (at exit unless
    ``BMCTL_MPC_COMPILE=detach``): the compiler's process group is terminated and its generated
    source, temporary library and lock removed. Returns the libraries whose compile was stopped."""
    import signal

    stopped = []
    for key, proc in list(_running.items()):
        if key not in _files or proc.poll() is not None:
            continue
        try:
            os.killpg(proc.pid, signal.SIGTERM)
        except (ProcessLookupError, PermissionError):  # not yet its own group: the child itself
            try:
                proc.send_signal(signal.SIGTERM)
            except OSError:
                pass
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            pass
        try:  # whatever of the group is left (a compiler forked while the signal went out)
            os.killpg(proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        proc.wait()
        for f in _files.pop(key):
            Path(f).unlink(missing_ok=True)
        _running.pop(key, None)
        stopped.append(Path(key).name)
    if stopped:
        print(f"bmctl: note: stopped {len(stopped)} unfinished background compile(s) ({', '.join(stopped)}); the "
              "solver ran interpreted. BMCTL_MPC_COMPILE=wait compiles in the foreground, =detach leaves the compile "
              "running after the command", file=sys.stderr)
    return stopped


#: a compile lock older than this is taken to be left by a killed process (the slowest compile,
#: the exact-Hessian NLP, takes 3-5 min at -O1)
LOCK_STALE_S = 1800.0


def _hessian_source(solver, c_path: Path, path: Path, sources: list) -> None:
    """Add to ``sources`` the C file of ``solver``'s Lagrangian Hessian ``nlp_hess_l`` when it was
    given as an option (``hess_lag``: the MPC's Gauss-Newton Hessian), which ``generate_dependencies``
    leaves out of ``c_path`` (nothing when the solver has none or the file already holds it). Without
    it the library does not load (IPOPT asks for ``nlp_hess_l`` and cannot differentiate the compiled
    NLP), so a Gauss-Newton solver would always run interpreted. Called in ``path``'s folder; the
    file is in ``sources`` from its creation, so the caller removes it should generating fail."""
    import casadi as ca

    if not (hasattr(solver, "has_function") and solver.has_function("nlp_hess_l")):  # a step library: none
        return
    if "nlp_hess_l(" in c_path.read_text(encoding="utf-8"):
        return
    h_file = _new_source_file(path)
    sources.append(h_file)
    gen = ca.CodeGenerator(Path(h_file).name, {"with_header": False})
    gen.add(solver.get_function("nlp_hess_l"))
    gen.generate()


def _new_source_file(path: Path) -> str:
    """A new, empty ``gen_<stem>_<hex>.c`` next to ``path``. casadi takes the file's stem as a C
    identifier and refuses a double underscore, which ``tempfile.mkstemp``'s random part (letters,
    digits and '_') can produce; a hex token cannot."""
    import secrets

    stem = path.stem.replace("-", "_")
    while True:
        name = path.parent / f"gen_{stem}_{secrets.token_hex(6)}.c"
        try:
            os.close(os.open(name, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600))
            return str(name)
        except FileExistsError:
            continue


def _lock_path(path: Path) -> Path:
    return path.with_name(path.name + ".lock")


def _lock_live(lock: Path) -> bool:
    """Whether ``lock`` exists and is younger than :data:`LOCK_STALE_S`."""
    import time

    try:
        return time.time() - lock.stat().st_mtime < LOCK_STALE_S
    except FileNotFoundError:
        return False


def _take_lock(lock: Path) -> bool:
    """Create ``lock`` exclusively (one compile of a library at a time across processes); a stale
    lock is replaced. False when another process holds it."""
    for _ in range(2):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600)
        except FileExistsError:
            if _lock_live(lock):
                return False
            lock.unlink(missing_ok=True)
            continue
        except OSError:
            return True  # no lock possible (odd file system): compile anyway, the rename stays atomic
        os.write(fd, str(os.getpid()).encode())
        os.close(fd)
        return True
    return False


def _wait_for_other(path: Path, lock: Path) -> None:
    """Block until another process's compile of ``path`` ended (its lock is gone) or went stale."""
    import time

    while _lock_live(lock) and not path.is_file():
        time.sleep(0.5)


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
