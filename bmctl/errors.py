"""Errors that the CLI turns into one-line messages with exit code 2."""

from __future__ import annotations

import math


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
        v = float(text)
    except ValueError:
        raise InputError(f"{where}: not a number: {text!r}") from None
    if not math.isfinite(v):
        raise InputError(f"{where}: must be a finite number (got {text})")
    return v
