"""Safe input and atomic output.

Input: :func:`read_input_bytes` is the one way bmctl reads a user's file -- a regular file
of a sane size, or a one-line :class:`bmctl.errors.InputError` (a FIFO, a device such as
/dev/zero, a symbolic link to one, a folder or a huge file never hangs or exhausts memory).
What is read is then parsed by a bounded reader: :func:`loads_json` and :func:`loads_toml`
refuse documents nested deeper than :data:`MAX_DEPTH` before parsing them, :func:`load_npz`
reads plain-data arrays whose headers declare no more than a size limit (checked before any
array is allocated, never a pickle or object array). A path named inside an input file is
taken only relative to that file's folder and must stay inside it (:func:`inside`), and a name
read from an input file becomes part of a file name only through :func:`name_part`.

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
import errno
import io
import itertools
import json
import os
import re
import stat
import tempfile
import zipfile
from pathlib import Path
from typing import Any, Iterable, Sequence

from .errors import InputError

#: default size limit of an input file (micrographs and tables are far smaller)
INPUT_MAX_BYTES = 1 << 30

_pending: list[list[tuple[Path, Path]]] = []  # stack of open output sets: (temporary, destination)
_created: list[list[Path]] = []  # with _pending: the folders each open set created, outermost first


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
        Empty, not found, a folder, not a regular file (FIFO, device, socket), or too large.
    """
    if os.fspath(path) == "":  # Path("") is the current folder
        raise InputError("'': empty path, expected a file")
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


#: the deepest nesting of lists and tables a JSON or TOML document may have (bmctl writes < 10)
MAX_DEPTH = 64
#: the most bytes the arrays of one ``.npz`` may declare (a trial checkpoint of 1e6 plant particles: ~50 MB)
NPZ_MAX_BYTES = 1 << 30

# Strings and comments to leave out before counting brackets. Every alternative matches from its
# opening character to the end of the text when unclosed (never fails and retries further on), so
# the scan is linear in the text whatever it holds.
_JSON_STRINGS = re.compile(r'"(?:[^"\\]|\\.)*(?:"|\\?\Z)', re.S)
_TOML_STRINGS = re.compile(r'"""(?:\\.|[^\\])*?(?:"""|\\?\Z)|\'\'\'.*?(?:\'\'\'|\Z)'
                           r'|"(?:[^"\\\n]|\\.)*(?:"|\\?(?=\n|\Z))|\'[^\'\n]*(?:\'|(?=\n|\Z))|#[^\n]*', re.S)
_BRACKETS = re.compile(r"[^\[\]{}]+")


def nesting_depth(text: str, toml: bool = False) -> int:
    """The deepest nesting of ``[``/``{`` in a JSON (or TOML) text, strings and comments left out.

    Linear in the text and without recursion, so it can be asked of any text before a
    recursive parser sees it.

    Parameters
    ----------
    text : str
        The document.
    toml : bool, optional
        TOML quoting (basic, literal and multi-line strings; ``#`` comments) instead of JSON's.

    Examples
    --------
    >>> nesting_depth('{"a": [1, [2, "[[["]]}')
    3
    """
    bare = (_TOML_STRINGS if toml else _JSON_STRINGS).sub("", text)
    steps = (1 if c in "[{" else -1 for c in _BRACKETS.sub("", bare))
    return max(itertools.accumulate(steps, initial=0))


def _too_deep(where: str, depth: int, max_depth: int) -> InputError:
    return InputError(f"{where}: nested {depth} levels deep (lists or tables inside each other), "
                      f"at most {max_depth}")


def loads_json(text: str | bytes, where: str, max_depth: int = MAX_DEPTH) -> Any:
    """Parse a JSON document bounded in depth; anything else is a one-line InputError naming ``where``.

    Parameters
    ----------
    text : str or bytes
        The document (bytes are decoded as UTF-8).
    where : str
        The file (and field) to name in a message.
    max_depth : int, optional
        Deepest nesting allowed (:data:`MAX_DEPTH`).

    Examples
    --------
    >>> loads_json('{"a": [1, 2]}', "x.json")
    {'a': [1, 2]}
    >>> loads_json("[" * 100 + "]" * 100, "x.json")
    Traceback (most recent call last):
    ...
    bmctl.errors.InputError: x.json: nested 100 levels deep (lists or tables inside each other), at most 64
    """
    try:
        if isinstance(text, (bytes, bytearray)):
            text = bytes(text).decode("utf-8")
        depth = nesting_depth(text)
        if depth > max_depth:
            raise _too_deep(where, depth, max_depth)
        return json.loads(text)
    except UnicodeDecodeError as exc:
        raise InputError(f"{where}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{where}: not JSON ({exc.msg} at line {exc.lineno}, column {exc.colno})") from None
    except (RecursionError, ValueError, TypeError) as exc:  # backstop: the depth check above comes first
        raise InputError(f"{where}: not a JSON document ({type(exc).__name__})") from None


def read_json(path: str | os.PathLike, max_bytes: int = INPUT_MAX_BYTES, max_depth: int = MAX_DEPTH) -> Any:
    """Read a JSON file through :func:`read_input_bytes` and :func:`loads_json`.

    Parameters
    ----------
    path : path-like
        The file.
    max_bytes : int, optional
        Size limit.
    max_depth : int, optional
        Deepest nesting allowed.
    """
    return loads_json(read_input_bytes(path, max_bytes), str(path), max_depth)


def loads_toml(text: str, where: str, max_depth: int = MAX_DEPTH) -> dict:
    """Parse a TOML document bounded in depth (checked before parsing); one-line InputError otherwise.

    Parameters
    ----------
    text : str
        The document.
    where : str
        The file to name in a message.
    max_depth : int, optional
        Deepest nesting of arrays and inline tables allowed (:data:`MAX_DEPTH`).

    Examples
    --------
    >>> loads_toml("a = [[1], [2]]", "x.toml")
    {'a': [[1], [2]]}
    """
    import tomllib

    depth = nesting_depth(text, toml=True)
    if depth > max_depth:
        raise _too_deep(where, depth, max_depth)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{where}: malformed TOML: {exc}") from None
    except RecursionError:  # backstop: the depth check above comes first
        raise InputError(f"{where}: malformed TOML: nested too deep") from None


def load_npz(source: str | os.PathLike | bytes, where: str, max_bytes: int = NPZ_MAX_BYTES) -> dict:
    """The arrays of a plain-data ``.npz`` (a file read through :func:`read_input_bytes`, or bytes).

    Every member must be a ``.npy`` array of a plain dtype (no object arrays, no pickles);
    the shapes its headers declare are read first, and a member that declares more bytes
    than it holds, or a file whose arrays declare more than ``max_bytes`` together, is
    refused before anything is allocated.

    Parameters
    ----------
    source : path-like or bytes
        The file, or its bytes.
    where : str
        What to name in a message.
    max_bytes : int, optional
        Limit on the declared size of all arrays together.
    """
    import numpy as np

    data = bytes(source) if isinstance(source, (bytes, bytearray)) else read_input_bytes(source)
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as zf:
            total = 0
            out = {}
            for info in zf.infolist():
                if not info.filename.endswith(".npy"):
                    raise InputError(f"{where}: {info.filename[:60]!r} is not an array (not a bmctl .npz)")
                with zf.open(info) as fh:
                    version = np.lib.format.read_magic(fh)
                    if version == (1, 0):
                        shape, _, dtype = np.lib.format.read_array_header_1_0(fh)
                    elif version == (2, 0):
                        shape, _, dtype = np.lib.format.read_array_header_2_0(fh)
                    else:
                        raise ValueError(f"npy format {version}")
                    if dtype.hasobject:
                        raise InputError(f"{where}: {info.filename[:-4][:60]!r}: an object array (plain data only)")
                    nbytes = dtype.itemsize
                    for n in shape:
                        nbytes *= int(n)
                    total += nbytes
                    if nbytes > info.file_size or total > max_bytes:
                        raise InputError(f"{where}: {info.filename[:-4][:60]!r}: declares a {shape} array "
                                         f"({nbytes:.3g} bytes) beyond its data or the limit of {max_bytes:.3g} bytes")
            with np.load(io.BytesIO(data), allow_pickle=False) as z:
                for k in z.files:
                    out[k] = z[k]
            return out
    except InputError:
        raise
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, TypeError, OverflowError,
            NotImplementedError, MemoryError) as exc:
        raise InputError(f"{where}: not a plain-data .npz (truncated or damaged: {type(exc).__name__})") from None


def inside(base: str | os.PathLike, ref: str, where: str) -> Path:
    """The file ``ref`` named inside an input file whose folder is ``base``: relative to
    ``base`` and, symbolic links resolved, inside it; otherwise a one-line InputError.

    A file given on the command line is named by the user; a file named inside it is read
    only from its own folder, so an input file cannot make bmctl read (or quote) anything
    else on the machine.

    Parameters
    ----------
    base : path-like
        The folder of the file that names ``ref``.
    ref : str
        The path as written in that file.
    where : str
        The file and field, for the message.

    Examples
    --------
    >>> inside("/tmp", "../etc/passwd", "h.toml: sample[0].table")
    Traceback (most recent call last):
    ...
    bmctl.errors.InputError: h.toml: sample[0].table: '../etc/passwd' leads outside the folder of the file that names it (/tmp)
    """
    if not ref or "\x00" in ref:
        raise InputError(f"{where}: an empty or invalid path")
    if Path(ref).is_absolute():
        raise InputError(f"{where}: {ref[:80]!r} must be a path relative to the folder of the file that names it")
    root = Path(os.path.realpath(base))
    real = Path(os.path.realpath(root / ref))
    if real != root and root not in real.parents:
        raise InputError(f"{where}: {ref[:80]!r} leads outside the folder of the file that names it ({base})")
    return Path(base) / ref


_UNSAFE = re.compile(r"[^A-Za-z0-9._+-]+")


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Whether paths ``a`` and ``b`` name one file: the same resolved path (symbolic links followed)
    or, where both exist, the same file by another name (a hard link).

    Examples
    --------
    >>> same_file("a/../b.csv", "b.csv"), same_file("a.csv", "b.csv")
    (True, False)
    """
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError):  # one of them does not exist (yet), or a name the system cannot take
        return False


def repeated_file(paths: Sequence[str | os.PathLike]) -> tuple[int, int] | None:
    """The first pair of ``paths`` that name one file (:func:`same_file`: the same resolved path, or
    the same file by another name), as (index of the earlier, index of the later); None when every
    path names its own file. One pass: each path is resolved and stat-ed once.

    Examples
    --------
    >>> repeated_file(["a.csv", "b.csv", "./a.csv"]), repeated_file(["a.csv", "b.csv"])
    ((0, 2), None)
    """
    seen: dict = {}  # what identifies a file (resolved path, device and inode) -> the first index naming it
    for i, p in enumerate(paths):
        keys: list = [os.path.realpath(p)]
        try:
            st = os.stat(p)
            keys.append((st.st_dev, st.st_ino))
        except (OSError, ValueError):  # missing, or a name the system cannot take: its path alone
            pass
        first = next((seen[k] for k in keys if k in seen), None)
        if first is not None:
            return first, i
        for k in keys:
            seen[k] = i
    return None


def name_part(text: str, max_len: int = 60) -> str:
    """``text`` (a name read from an input file) as a safe part of a file name: letters,
    digits and ``._+-`` kept, every other run of characters one ``_``, no leading dot,
    at most ``max_len`` characters; never a path.

    Parameters
    ----------
    text : str
        The name.
    max_len : int, optional
        Longest result.

    Examples
    --------
    >>> name_part("../../../X")
    'X'
    >>> name_part("run 1: 300 rpm")
    'run_1_300_rpm'
    """
    out = _UNSAFE.sub("_", str(text)).strip("._-")[:max_len].rstrip("._-")
    return out or "unnamed"


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _make_folder(folder: Path) -> list[Path]:
    """Create ``folder`` with its missing ancestors; returns the ones created, outermost first."""
    missing, p = [], folder
    while not os.path.lexists(p) and p != p.parent:
        missing.append(p)
        p = p.parent
    folder.mkdir(parents=True, exist_ok=True)
    return missing[::-1]


def _remove_empty(folders: list[Path]) -> None:
    """Remove the folders a failed write created, innermost first, where nothing else was put in them."""
    for d in reversed(folders):
        with contextlib.suppress(OSError):
            d.rmdir()


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
    for the whole set. A failed write removes the folders it created where they stayed empty.

    Parameters
    ----------
    path : path-like
        Final destination (a symbolic link is written through).
    suffix : str, optional
        Suffix for the temporary file (some writers, e.g. matplotlib, infer the
        format from it).
    """
    path = _destination(path)
    created: list[Path] = []  # folders this write made: removed again if it fails (outside a set)
    try:
        created = _make_folder(path.parent)
        if _created:
            _created[-1].extend(created)  # the set removes them if it fails
            created = []
        if path.is_dir():
            raise IsADirectoryError(21, "is a folder, cannot be written as a file", str(path))
        if path.exists() and not path.is_file():  # a rename would replace the pipe or device itself
            raise OSError(errno.EINVAL, "not a regular file (a pipe, device or socket is not replaced by an output)",
                          str(path))
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix or path.suffix, dir=path.parent)
        os.fchmod(fd, 0o666 & ~_umask())
    except OSError as exc:  # name the destination, not the temporary file
        _remove_empty(created)
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
        _remove_empty(created)
        raise


@contextlib.contextmanager
def output_set():
    """Write several files as one set: each is renamed into place only when all are written.

    A failure inside the block (an exception, Ctrl-C) removes every temporary file of the set
    and the folders it created that stayed empty, and leaves the destinations as they were.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> with output_set():
    ...     write_text(d / "a.txt", "a")
    ...     (d / "a.txt").exists()
    False
    >>> (d / "a.txt").read_text(encoding="utf-8")
    'a'
    """
    _pending.append([])
    _created.append([])
    try:
        yield
    except BaseException:
        for tmp, _ in _pending.pop():
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
        _remove_empty(_created.pop())  # the folders the set made, where they stayed empty
        raise
    todo = _pending.pop()
    made = _created.pop()
    if _pending:  # a set inside a set commits with the outer one
        _pending[-1].extend(todo)
        _created[-1].extend(made)
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
        tmp.write_text(text, encoding="utf-8")


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


#: the escapes of a TOML basic string (the other control characters are written \uXXXX)
_TOML_ESCAPES = {'"': '\\"', "\\": "\\\\", "\b": "\\b", "\t": "\\t", "\n": "\\n", "\f": "\\f", "\r": "\\r"}


def toml_string(text: str) -> str:
    """``text`` as a TOML basic string: quoted, with ``"``, ``\\`` and control characters escaped.

    Parameters
    ----------
    text : str

    Examples
    --------
    >>> print(toml_string('lab "A" \\\\ 2'))
    "lab \\"A\\" \\\\ 2"
    """
    out = []
    for ch in str(text):
        if ch in _TOML_ESCAPES:
            out.append(_TOML_ESCAPES[ch])
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04X}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'
