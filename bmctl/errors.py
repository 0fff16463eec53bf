"""Errors that the CLI turns into one-line messages with exit code 2."""

from __future__ import annotations

import math
import re

#: the longest message printed (characters); a longer one keeps its head and its end
MESSAGE_MAX_CHARS = 600
#: the longest quoted value inside a message
QUOTE_MAX_CHARS = 60
_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f\u2028\u2029]")


class InputError(Exception):
    """Bad user input: a file, a field, a flag or a value.

    The message is one line and names where the problem is (file and field),
    e.g. ``models/x.toml: material.yield_stress_Pa: must be > 0 (got -1)``.
    The CLI prints it as ``bmctl: error: <message>`` and exits with status 2.

    Parameters
    ----------
    message : str
        What is wrong, naming the file and field.
    """


def require_generator(rng, name: str) -> None:
    """Refuse anything but a ``numpy.random.Generator`` for the argument ``name`` (every random draw
    flows from one the user seeded), naming it.

    >>> import numpy as np
    >>> require_generator(np.random.default_rng(0), "rng")
    >>> require_generator(5, "rng")
    Traceback (most recent call last):
    ...
    TypeError: rng: must be a numpy.random.Generator (np.random.default_rng(seed)), got int
    """
    import numpy as np

    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"{name}: must be a numpy.random.Generator (np.random.default_rng(seed)), "
                        f"got {type(rng).__name__}")


def require_whole(value, name: str, lo: int = 0) -> int:
    """A whole number >= ``lo`` for the argument ``name`` (a seed, a count), as an int: a bool, a float
    (1.5 was cut to 1), a string or None is a TypeError and one below ``lo`` an InputError, each
    naming it.

    >>> require_whole(3, "seeds", 1)
    3
    >>> require_whole(1.5, "seeds", 1)
    Traceback (most recent call last):
    ...
    TypeError: seeds: must be a whole number >= 1 (got float 1.5)
    """
    import numbers

    import numpy as np

    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name}: must be a whole number >= {lo} (got {type(value).__name__} {value!r})")
    if int(value) < lo:
        raise InputError(f"{name}: must be >= {lo} (got {int(value)})")
    return int(value)


def finite_float(text: str, where: str) -> float:
    """Parse one finite number given by the user, or raise a one-line :class:`InputError`.

    Parameters
    ----------
    text : str
        The text as given (a flag value, a list item, a ``key=value`` value).
    where : str
        What to name in the message, e.g. ``"--hours"`` or ``"--target: s_mean_um"``.
    """
    try:
        if "_" in str(text):  # Python reads "4_0" as 40; a user's digits with a stray underscore are a typo
            raise ValueError
        v = float(text)
    except ValueError:
        raise InputError(f"{where}: not a number: {text!r}") from None
    if not math.isfinite(v):
        raise InputError(f"{where}: must be a finite number (got {text})")
    return v


def quote(value, limit: int = QUOTE_MAX_CHARS) -> str:
    """``repr(value)`` for a message: one line, at most ``limit`` characters (then ``...`` and the count).

    Parameters
    ----------
    value : object
        What to quote (text from a file, a flag's value).
    limit : int, optional
        Longest quotation.

    Examples
    --------
    >>> quote("a\\nb")
    "'a\\\\nb'"
    >>> quote("x" * 100, 10)
    "'xxxxxxxxx... (100 characters)"
    """
    size = len(value) if isinstance(value, (str, bytes, bytearray)) else None
    text = one_line(repr(value[: limit + 1] if size is not None else value), 10 * limit)
    if len(text) > limit:
        return f"{text[:limit]}... ({size if size is not None else len(text)} characters)"
    return text


def one_line(text: str, limit: int = MESSAGE_MAX_CHARS) -> str:
    """``text`` as one line of at most about ``limit`` characters: every control character
    (a newline, a carriage return, a tab, an escape) written as its escape (``\\n``), and a
    longer text cut in the middle (its head names the file and field, its end the reason).

    Parameters
    ----------
    text : str
        A message.
    limit : int, optional
        Longest result.

    Examples
    --------
    >>> one_line("x.toml: key 'a\\nb': unknown field")
    "x.toml: key 'a\\\\nb': unknown field"
    """
    text = _CONTROL.sub(lambda m: repr(m.group())[1:-1], str(text))
    if len(text) > limit:
        head, tail = limit * 2 // 3, limit // 3 - 30
        text = f"{text[:head]} ... ({len(text) - head - tail} characters left out) ... {text[-tail:]}"
    return text
