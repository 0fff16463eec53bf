"""Safe input and atomic output.

Input: :func:`read_input_bytes` is the one way bmctl reads a user's file -- a regular file
of a sane size, or a one-line :class:`bmctl.errors.InputError` (a FIFO, a device such as
/dev/zero, a folder or a huge file never hangs or exhausts memory).

Output: every file is written to a temporary sibling and renamed into place, with the
permissions the user's umask gives a new file (as ``open`` would). A reader never sees a
half-written file, and a failure (bad input found late, Ctrl-C, a full disk) leaves any
earlier version of the file untouched and names the real file, not the temporary one. A
destination that is a symbolic link is written through (the link stays a link). Inside
:func:`output_set`, the renames wait until every file of the set is written: a late failure
leaves none of the set's new files.
"""

from __future__ import annotations

import contextlib
import csv
import io
import os
import stat
import tempfile
from pathlib import Path
from typing import Iterable, Sequence

from .errors import InputError

#: default size limit of an input file (micrographs and tables are far smaller)
INPUT_MAX_BYTES = 1 << 30

_pending: list[list[tuple[Path, Path]]] = []  # stack of open output sets: (temporary, destination)


def check_input_file(path: str | os.PathLike, max_bytes: int = INPUT_MAX_BYTES) -> Path:
    """Check that ``path`` is a readable regular file of at most ``max_bytes``; returns it.

    Parameters
    ----------
    path : path-like
        The input file.
    max_bytes : int, optional
        Size limit.

    Raises
    ------
    InputError
        Not found, a folder, not a regular file (FIFO, device, socket), or too large.
    """
    p = Path(path)
    try:
        st = os.stat(p)
    except FileNotFoundError:
        raise InputError(f"{p}: file not found (no such file or folder)") from None
    except OSError as exc:
        raise InputError(f"{p}: cannot read: {exc.strerror or exc}") from None
    if stat.S_ISDIR(st.st_mode):
        raise InputError(f"{p}: is a directory, expected a file")
    if not stat.S_ISREG(st.st_mode):
        raise InputError(f"{p}: not a regular file (a pipe, device or socket cannot be an input)")
    if st.st_size > max_bytes:
        raise InputError(f"{p}: file too large ({st.st_size} bytes, limit {max_bytes})")
    return p


def read_input_bytes(path: str | os.PathLike, max_bytes: int = INPUT_MAX_BYTES) -> bytes:
    """Read a user's input file (see :func:`check_input_file`) without following it into a
    FIFO or device, and never more than ``max_bytes``.

    Parameters
    ----------
    path : path-like
        The input file.
    max_bytes : int, optional
        Size limit.
    """
    p = check_input_file(path, max_bytes)
    try:  # O_NONBLOCK: should the file be swapped for a FIFO after the check, open does not hang
        fd = os.open(p, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as exc:
        raise InputError(f"{p}: cannot read: {exc.strerror or exc}") from None
    with os.fdopen(fd, "rb") as fh:
        if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):
            raise InputError(f"{p}: not a regular file (a pipe, device or socket cannot be an input)")
        data = fh.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise InputError(f"{p}: file too large (over {max_bytes} bytes)")
    return data


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _destination(path: str | os.PathLike) -> Path:
    """Where a write to ``path`` lands: through a symbolic link to its target."""
    p = Path(path)
    if p.is_symlink():
        return Path(os.path.realpath(p))
    return p


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str = ""):
    """Yield a temporary path next to ``path``; rename it onto ``path`` on success.

    The file gets the permissions of a new file under the user's umask (``0o666 & ~umask``).
    Errors name ``path``, never the temporary file. Inside :func:`output_set` the rename waits
    for the whole set.

    Parameters
    ----------
    path : path-like
        Final destination (a symbolic link is written through).
    suffix : str, optional
        Suffix for the temporary file (some writers, e.g. matplotlib, infer the
        format from it).
    """
    path = _destination(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        if path.is_dir():
            raise IsADirectoryError(21, "is a folder, cannot be written as a file", str(path))
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix or path.suffix, dir=path.parent)
        os.fchmod(fd, 0o666 & ~_umask())
    except OSError as exc:  # name the destination, not the temporary file
        raise OSError(exc.errno, exc.strerror, str(path)) from None
    os.close(fd)
    try:
        try:
            yield Path(tmp)
            if _pending:
                _pending[-1].append((Path(tmp), path))
            else:
                os.replace(tmp, path)
        except OSError as exc:
            raise OSError(exc.errno, exc.strerror, str(path)) from None
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


@contextlib.contextmanager
def output_set():
    """Write several files as one set: each is renamed into place only when all are written.

    A failure inside the block (an exception, Ctrl-C) removes every temporary file of the set
    and leaves the destinations as they were.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> with output_set():
    ...     write_text(d / "a.txt", "a")
    ...     (d / "a.txt").exists()
    False
    >>> (d / "a.txt").read_text()
    'a'
    """
    _pending.append([])
    try:
        yield
    except BaseException:
        for tmp, _ in _pending.pop():
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
        raise
    todo = _pending.pop()
    if _pending:  # a set inside a set commits with the outer one
        _pending[-1].extend(todo)
        return
    for i, (tmp, dest) in enumerate(todo):
        try:
            os.replace(tmp, dest)
        except OSError as exc:
            for t, _ in todo[i:]:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(t)
            raise OSError(exc.errno, exc.strerror, str(dest)) from None


def write_text(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def csv_text(header: Sequence[str], rows: Iterable[Sequence], fmt: str = "{:.6g}") -> str:
    """Format rows as CSV text with a header; floats use ``fmt``.

    Parameters
    ----------
    header : sequence of str
        Column names.
    rows : iterable of sequences
        Row values (numbers or strings).
    fmt : str, optional
        Format for floats.
    """
    import numpy as np  # here, not at module level: the CLI imports bmctl.io without numpy

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    for row in rows:
        w.writerow([fmt.format(v) if isinstance(v, (float, np.floating)) else v for v in row])
    return buf.getvalue()


def write_csv(path: str | os.PathLike, header: Sequence[str], rows: Iterable[Sequence], fmt: str = "{:.6g}") -> None:
    """Write a CSV file atomically (see :func:`csv_text`)."""
    write_text(path, csv_text(header, rows, fmt))


def savez(path: str | os.PathLike, **arrays) -> None:
    """Save arrays to a compressed ``.npz`` atomically."""
    import numpy as np

    with atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **arrays)


def pyplot():
    """``matplotlib.pyplot`` on the non-interactive Agg backend, imported on first use (figures
    only: the numerical paths never pay for importing matplotlib)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def savefig(fig, path: str | os.PathLike, **kwargs) -> None:
    """Save a matplotlib figure atomically and close it."""
    import matplotlib.pyplot as plt

    with atomic_path(path, suffix=Path(path).suffix) as tmp:
        fig.savefig(tmp, **kwargs)
    plt.close(fig)
