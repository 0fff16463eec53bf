"""How messages name the arguments they refuse: as a Python caller spells them, or as the flags of
the command that passed them on.

A library function names an argument through :func:`arg` (``arg("um_per_px")``); called from
Python the message says ``um_per_px``, and a command that runs it within :func:`naming` (its
table ``{"um_per_px": "--um-per-px"}``) gets the same message naming its flag ``--um-per-px``.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Mapping
from contextvars import ContextVar

#: how messages name arguments (:func:`arg`): None as Python spells them, else a table
#: {argument: name} that :func:`naming` sets (a command: its flags)
_NAMES: ContextVar[Mapping[str, str] | None] = ContextVar("bmctl_argument_names", default=None)


def arg(name: str) -> str:
    """An argument as a message names it: ``name``, as a Python caller spells it (``"hours"``; a
    switch with its value, ``"accept=False"``), or within :func:`naming` the name its table gives
    (a command: its flag, ``"--hours"``, ``"--reject"``).

    Parameters
    ----------
    name : str
        The argument as a Python caller spells it.

    Returns
    -------
    str
        How the message names it.

    Examples
    --------
    >>> arg("temperature_max_c")
    'temperature_max_c'
    >>> with naming({"temperature_max_c": "--temperature-max-c"}):
    ...     arg("temperature_max_c")
    '--temperature-max-c'
    """
    names = _NAMES.get()
    return name if names is None else names.get(name, name)


@contextlib.contextmanager
def naming(names: Mapping[str, str]) -> Iterator[None]:
    """Within the block, messages name each argument by ``names`` (:func:`arg`; one it does not
    hold as Python spells it); the commands run the library so, naming their flags. As a
    decorator (``@naming({...})``) it holds for each call of the function.

    Parameters
    ----------
    names : mapping of str to str
        ``{argument: name}``, the argument as :func:`arg` takes it.

    Examples
    --------
    >>> @naming({"um_per_px": "--um-per-px"})
    ... def command():
    ...     return arg("um_per_px")
    >>> command(), arg("um_per_px")
    ('--um-per-px', 'um_per_px')
    """
    token = _NAMES.set(dict(names))
    try:
        yield
    finally:
        _NAMES.reset(token)
