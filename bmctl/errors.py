"""Errors that the CLI turns into one-line messages with exit code 2."""

from __future__ import annotations


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
