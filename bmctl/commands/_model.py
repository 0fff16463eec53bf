"""Shared by the commands that run a moment model: the ``--identify`` flag, the loader and its lines."""

from __future__ import annotations

import sys
import time

IDENTIFY_HELP = ("when the card has no moment coefficients of its own (<card>.moments.toml next to it, with a "
                 "matching card fingerprint), identify them now (about a minute) instead of refusing")


def add_identify_flag(p) -> None:
    """Add ``--identify`` (:data:`IDENTIFY_HELP`) to a command's parser."""
    p.add_argument("--identify", action="store_true", help=IDENTIFY_HELP)


def progress_printer(prefix: str = "identify"):
    """A progress callback printing ``[  12.3 s] identify: <line>`` on stderr."""
    t0 = time.time()

    def log(msg: str) -> None:
        print(f"[{time.time() - t0:6.1f} s] {prefix}: {msg}", file=sys.stderr, flush=True)

    return log


def model_for(card_path, identify: bool = False):
    """:func:`bmctl.moments.for_card` of ``card_path`` with identification progress on stderr."""
    from ..moments import for_card

    return for_card(card_path, identify=identify, progress=progress_printer())


def heldout_text(model) -> str:
    """``held-out NRMSE s_mean 2.2 %, ...`` of the model's coefficients (empty when it has none)."""
    f = getattr(model, "coeff_file", None)
    return "" if f is None else f.heldout_line()


def warn_window(model, rpms, where: str = "") -> None:
    """Print the operating-window warning (:func:`bmctl.cards.window_warnings`) for the speeds in use."""
    from ..cards import window_warnings

    f = getattr(model, "coeff_file", None)
    for line in window_warnings(model.card, rpms, f.window if f is not None else None):
        print(f"bmctl: warning: {where}{line}", file=sys.stderr)
