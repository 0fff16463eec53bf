"""Atomic output: every file is written to a temporary sibling and renamed into place.

A reader never sees a half-written file, and a failure (bad input found late,
Ctrl-C) leaves any earlier version of the file untouched.
"""

from __future__ import annotations

import contextlib
import csv
import io
import os
import tempfile
from pathlib import Path
from typing import Iterable, Sequence


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str = ""):
    """Yield a temporary path next to ``path``; rename it onto ``path`` on success.

    Parameters
    ----------
    path : path-like
        Final destination.
    suffix : str, optional
        Suffix for the temporary file (some writers, e.g. matplotlib, infer the
        format from it).
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix or path.suffix, dir=path.parent)
    except OSError as exc:  # name the destination, not the temporary file
        raise OSError(exc.errno, exc.strerror, str(path)) from None
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


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
