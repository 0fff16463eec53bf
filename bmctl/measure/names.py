"""A user's path as text that can be printed, drawn and written to a UTF-8 table.

A file name on Linux is bytes; Python holds bytes that are not UTF-8 as lone surrogates
(``'\\udcff'``), which a UTF-8 file, a strict terminal and matplotlib's text cannot take.
:func:`path_text` writes each such byte as its escape (``\\xff``), and each control character
(a newline, a tab, an escape) as its escape (``\\n``), as error messages do; every other path
is returned as it is.
"""

from __future__ import annotations

import os


def path_text(path: str | os.PathLike) -> str:
    """``path`` as printable text on one line: bytes that are not UTF-8 as ``\\xNN`` escapes,
    control characters as theirs (``\\n``).

    Parameters
    ----------
    path : path-like
        A path as given on the command line (or joined from one).

    Returns
    -------
    str
        The path, unchanged unless it holds bytes that are not UTF-8 or control characters.

    Examples
    --------
    >>> path_text("a/b.png")
    'a/b.png'
    >>> path_text(b"bad\\xff.png".decode("utf-8", "surrogateescape"))
    'bad\\\\xff.png'
    >>> path_text("two\\nlines.png")
    'two\\\\nlines.png'
    """
    from ..errors import _CONTROL

    text = os.fspath(path)
    if isinstance(text, bytes):
        text = os.fsdecode(text)
    try:
        text = text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
    except UnicodeEncodeError:  # a surrogate that stands for no byte (not from a file name)
        text = text.encode("utf-8", "backslashreplace").decode("utf-8")
    # a newline or escape in a name would split or garble the line it is printed on: escaped as
    # an error message escapes it (bmctl.errors.one_line)
    return _CONTROL.sub(lambda m: repr(m.group())[1:-1], text)


def refuse_repeats(paths, prefix: str = "") -> None:
    """Refuse a file named twice among ``paths`` (the same file by any path): one image or table
    counted twice would read as a sample twice its size. Items that are not paths (tables in
    memory) are skipped.

    Examples
    --------
    >>> refuse_repeats(["a.csv", "b.csv"])
    >>> refuse_repeats(["a.csv", "./a.csv"], "sample: ")
    Traceback (most recent call last):
    ...
    bmctl.errors.InputError: sample: ./a.csv: given twice (each image or table is one part of the sample)
    """
    from ..errors import InputError

    seen = set()
    for p in paths:
        if hasattr(p, "s_um"):
            continue
        key = os.path.realpath(p)
        if key in seen:
            raise InputError(f"{prefix}{path_text(p)}: given twice (each image or table is one part of the sample)")
        seen.add(key)
