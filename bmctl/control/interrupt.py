"""Ctrl-C during a CasADi solve.

CasADi checks Python's signals while IPOPT iterates, catches the ``KeyboardInterrupt`` and ends
the solve as ``NonIpopt_Exception_Thrown``: the caller would take that for a failed solve, fall
back, and the run would carry on. :func:`keep_interrupts` notes a SIGINT that arrives during the
block and raises ``KeyboardInterrupt`` when the block ends, so the CLI stops with its one line
(exit 130) and a trial keeps its checkpoint.
"""

from __future__ import annotations

import contextlib
import signal
import threading


@contextlib.contextmanager
def keep_interrupts():
    """Raise ``KeyboardInterrupt`` after the block if SIGINT arrived during it (main thread only;
    elsewhere, and where SIGINT is not Python's to handle, the block runs as it is).

    Examples
    --------
    >>> with keep_interrupts():
    ...     pass
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.getsignal(signal.SIGINT)
    if not callable(previous):  # ignored or the OS default: nothing of Python's to keep
        yield
        return
    hit = []

    def note(signum, frame):
        hit.append(signum)
        previous(signum, frame)  # Python's handler raises KeyboardInterrupt, which CasADi may swallow

    signal.signal(signal.SIGINT, note)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if hit:
        raise KeyboardInterrupt
