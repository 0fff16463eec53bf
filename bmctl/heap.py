"""The ``bmctl`` command's glibc heap setting, kept free of numpy so that ``bmctl --help`` stays light."""
from __future__ import annotations


def keep_heap() -> None:
    """Let glibc's malloc keep freed memory at the top of the heap (M_TOP_PAD) and serve blocks below 32 MiB
    from it (M_MMAP_THRESHOLD): the field's temporaries (up to a few hundred kB each for a batch of a
    thousand states) are otherwise handed back to the kernel and faulted in again on every call, which
    costs as much as the arithmetic. A process-wide setting, so the library never makes it on import:
    the ``bmctl`` command makes it at start, and a program that calls the field in a loop may. Results
    do not change; off Linux or without glibc nothing happens.

    Examples
    --------
    >>> from bmctl.moments.npfield import keep_heap
    >>> keep_heap()
    """
    import sys

    if not sys.platform.startswith("linux"):
        return
    try:
        import ctypes

        mallopt = ctypes.CDLL(None).mallopt
        mallopt(-2, 64 << 20)  # M_TOP_PAD
        mallopt(-3, 32 << 20)  # M_MMAP_THRESHOLD
    except (OSError, AttributeError):  # not glibc
        pass
