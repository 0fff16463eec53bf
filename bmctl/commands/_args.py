"""Argument parsers shared by the subcommands: bad values become one-line InputErrors."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from ..errors import InputError, finite_float

#: the library's arguments that its messages name (:func:`bmctl.naming.arg`), as the flags of the
#: commands that pass them on: each such command runs within :func:`bmctl.naming.naming` of this table,
#: so its refusals name ``--um-per-px`` where a Python caller reads ``um_per_px``; a key holds for every such
#: command, so each is one that every command passing the argument spells the same way
LIBRARY_FLAGS = {"um_per_px": "--um-per-px", "scale_bar_um": "--scale-bar-um", "identify=True": "--identify",
                 "min_particles": "--min-particles", "min_area_px": "--min-area-px", "crop": "--crop",
                 "at_h": "--at-h", "start": "--start", "workers": "--workers", "scheduler": "--scheduler"}


def shipped(folder: str, flag: str) -> Path:
    """The shipped ``folder`` (``"models"``, ``"controllers"``: a clone's, or the copy a wheel
    carries; :func:`bmctl.shipped.shipped_dir`), or :class:`InputError` naming ``flag`` where this
    installation has neither (a package copied without them): the defaults that read it need a
    complete installation, or the file given.

    Parameters
    ----------
    folder : str
        ``"models"`` or ``"controllers"``.
    flag : str
        The option that gives the file instead (named in the message).
    """
    from .. import shipped as S

    path = S.shipped_dir(folder)
    if path is None:
        raise InputError(f"{flag}: not given, and this installation of bmctl ({S.PACKAGED.parent}) has no shipped "
                         f"{folder}/ folder (reinstall bmctl with pip install . or pip install -e ., or give {flag})")
    return path


#: the controller of ``design`` and ``campaign init`` when none is given (the shipped MPC)
DEFAULT_CONTROLLER = "controllers/mpc-default.toml"


def controller_path(given) -> Path:
    """The controller file a command uses: ``given``, else :data:`DEFAULT_CONTROLLER` in the working
    folder (a user's own copy), else the shipped one (:func:`shipped`).

    Parameters
    ----------
    given : str or path-like or None
        ``--controller`` as given.
    """
    if given is not None:
        return Path(given)
    local = Path(DEFAULT_CONTROLLER)
    if local.exists():
        return local
    return shipped("controllers", "--controller") / local.name


def progress_bar(**kw):
    """A tqdm progress bar on stderr, shown only when stderr is a terminal (``disable=None``) and
    cleared when closed: a log or a pipe gets no bar fragments before the result or an error line.

    Parameters
    ----------
    **kw
        tqdm's arguments (``desc``, ``unit``, ``total``, ``bar_format``, ...).
    """
    import sys

    from tqdm import tqdm

    return tqdm(**{"file": sys.stderr, "leave": False, "disable": None, **kw})


def output_path(path, name: str = "--out", folder: bool = True) -> Path:
    """Check an output folder (``folder``) or file before any work is done; returns it as a Path.

    No folder is created: the check resolves symbolic links (a write goes where the link
    points; the link itself is never replaced), finds the nearest existing ancestor of the
    resolved path and creates (and at once removes) a temporary file there, so a run with a
    mistyped or read-only ``--out`` fails at once with one line instead of after the computation.

    Parameters
    ----------
    path : path-like
        The output folder or file.
    name : str, optional
        The flag, named in error messages.
    folder : bool, optional
        True for an output folder, False for an output file.
    """
    raw = os.fspath(path)
    if raw == "":  # Path("") is the current folder
        raise InputError(f"{name}: empty path")
    if not folder and raw.endswith(("/", os.sep)):  # Path drops the slash: a file would be written under that name
        raise InputError(f"{name}: {raw} ends in '/', naming a folder; expected a file")
    p = Path(path)
    real = Path(os.path.realpath(p))
    shown = p if real == p.absolute() else f"{p} (-> {real})"
    if real.exists():
        if folder and not real.is_dir():
            raise InputError(f"{name}: {shown} exists and is not a folder")
        if not folder and real.is_dir():
            raise InputError(f"{name}: {shown} is a folder, expected a file")
        if not folder and not real.is_file():
            raise InputError(f"{name}: {shown} is not a regular file")
    anc = real if (folder and real.exists()) else real.parent
    while not anc.exists() and anc != anc.parent:
        anc = anc.parent
    if not anc.is_dir():
        raise InputError(f"{name}: cannot create {shown}: {anc} is not a folder")
    try:  # a probe file, removed at once: permissions, read-only or virtual file systems
        with tempfile.TemporaryFile(dir=anc):
            pass
    except OSError as exc:
        raise InputError(f"{name}: cannot write {shown}: {exc.strerror or exc} ({anc})") from None
    return p


def int_arg(name: str, lo: int | None = None, hi: int | None = None):
    """argparse ``type=`` for an integer flag within [lo, hi] (either bound optional).

    Parameters
    ----------
    name : str
        The flag, named in error messages.
    lo, hi : int, optional
        Inclusive bounds.
    """

    def parse(text: str) -> int:
        try:
            if "_" in str(text):  # Python reads "1_0" as 10: a typo, not a number
                raise ValueError
            v = int(text)
        except ValueError:
            raise InputError(f"{name}: not an integer: {text!r}") from None
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            bound = f">= {lo}" if hi is None else (f"<= {hi}" if lo is None else f"in [{lo}, {hi}]")
            raise InputError(f"{name}: must be {bound} (got {v})")
        return v

    return parse


def float_arg(name: str, lo: float | None = None, hi: float | None = None, strict: bool = False):
    """argparse ``type=`` for a finite number flag within [lo, hi] (``strict``: lo excluded).

    Parameters
    ----------
    name : str
        The flag, named in error messages.
    lo, hi : float, optional
        Bounds.
    strict : bool, optional
        Exclude ``lo`` itself.
    """

    def parse(text: str) -> float:
        v = finite_float(text, name)
        if lo is not None and (v < lo or (strict and v == lo)):
            raise InputError(f"{name}: must be {'>' if strict else '>='} {lo:g} (got {text})")
        if hi is not None and v > hi:
            raise InputError(f"{name}: must be <= {hi:g} (got {text})")
        return v

    return parse


def hours_arg(name: str, zero: bool = False):
    """argparse ``type=`` for a duration or a time in hours: in [1 s, 1000 h] (``zero``: 0 allowed
    too), the range every schedule, scenario and campaign shares (:mod:`bmctl.limits`).

    Parameters
    ----------
    name : str
        The flag, named in error messages.
    zero : bool, optional
        Whether 0 h is a valid value (a time, not a duration).
    """
    from ..limits import HOURS_MAX, HOURS_MIN

    def parse(text: str) -> float:
        v = finite_float(text, name)
        if not (v == 0 and zero) and not HOURS_MIN <= v <= HOURS_MAX:
            lo = "0 or " if zero else ""
            raise InputError(f"{name}: must be {lo}in [{HOURS_MIN * 3600:g} s, {HOURS_MAX:g} h] (got {text})")
        return v

    return parse


def rpm_arg(name: str):
    """argparse ``type=`` for a sun-disc speed in [0, 2000] rpm (:data:`bmctl.limits.RPM_MAX`; a
    card's ``mill.rpm_max`` caps it further where the command knows the card).

    Parameters
    ----------
    name : str
        The flag, named in error messages.
    """
    from ..limits import RPM_MAX

    return float_arg(name, lo=0.0, hi=RPM_MAX)
