"""Argument parsers shared by the subcommands: bad values become one-line InputErrors."""

from __future__ import annotations


from ..errors import InputError, finite_float


def int_arg(name: str, lo: int | None = None, hi: int | None = None):
    """argparse ``type=`` for an integer flag within [lo, hi] (either bound optional).

    Parameters
    ----------
    name : str
        The flag, named in error messages.
    lo, hi : int, optional
        Inclusive bounds.
    """

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise InputError(f"{name}: not an integer: {text!r}") from None
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            bound = f">= {lo}" if hi is None else (f"<= {hi}" if lo is None else f"in [{lo}, {hi}]")
            raise InputError(f"{name}: must be {bound} (got {v})")
        return v

    return parse


def float_arg(name: str, lo: float | None = None, hi: float | None = None, strict: bool = False):
    """argparse ``type=`` for a finite number flag within [lo, hi] (``strict``: lo excluded).

    Parameters
    ----------
    name : str
        The flag, named in error messages.
    lo, hi : float, optional
        Bounds.
    strict : bool, optional
        Exclude ``lo`` itself.
    """

    def parse(text: str) -> float:
        v = finite_float(text, name)
        if lo is not None and (v < lo or (strict and v == lo)):
            raise InputError(f"{name}: must be {'>' if strict else '>='} {lo:g} (got {text})")
        if hi is not None and v > hi:
            raise InputError(f"{name}: must be <= {hi:g} (got {text})")
        return v

    return parse
