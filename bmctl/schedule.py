"""One schedule type: segments of (hours, rpm, milling share), with its conversions.

A :class:`Schedule` is what a card's recipe, a schedule TOML, a controller's plan, a what-if,
an identification experiment and a verification run all speak. A segment mills at ``rpm``
for ``milling * hours``, then rests for the remainder; rpm 0 is a rest.

Iterating a schedule yields ``(hours, rpm)`` pairs with the milling share expanded into a
milling piece and a rest piece (:meth:`Schedule.pairs`), so a schedule can be given wherever
the plant takes a sequence of ``(hours, rpm)`` pairs.

TOML form (``bmctl simulate --schedule``, ``bmctl whatif``)::

    name = "ramp-with-rests"
    [[segment]]
    hours = 1.0
    rpm = 300
    # milling = 1.0   (optional share of the segment spent milling)

A share strictly between 0 and 1 must leave a milling phase and a rest phase of at least
:data:`~bmctl.limits.PHASE_MIN_MINUTES` (6 s) each, the shortest phase any mill is run for.
The segments' hours may add up to at most :data:`~bmctl.limits.HOURS_MAX` (1,000 h), the longest
batch (each segment is held to that already).

Examples
--------
>>> s = Schedule.from_pairs([(1.0, 300.0), (0.5, 0.0)])
>>> s.hours, list(s)
(1.5, [(1.0, 300.0), (0.5, 0.0)])
>>> s.inputs_between(0.5, 2.0)
[(300.0, 1.0, 0.5), (0.0, 0.0, 0.5), (0.0, 0.0, 0.5)]
>>> Schedule.from_inputs([[300.0, 0.5], [300.0, 1.0]], 0.5).pairs()
[(0.25, 300.0), (0.25, 0.0), (0.5, 300.0)]
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Iterator, Sequence

import numpy as np
from pydantic import Field, ValidationInfo, field_validator

from .config import HOURS, RPM, Strict, load
from .limits import HOURS_MAX, PHASE_MIN_MINUTES
from .physics.constants import TIME_EPS_H

#: pieces shorter than this (h) are dropped when a schedule is cut or merged
PIECE_EPS_H = 1e-12


class SegmentSpec(Strict):
    """One ``[[segment]]`` table."""

    hours: HOURS
    rpm: RPM
    milling: float = Field(default=1.0, ge=0.0, le=1.0)

    @field_validator("milling", mode="after")
    @classmethod
    def _phases_long_enough(cls, milling: float, info: ValidationInfo) -> float:
        """Refuse a share that leaves a milling or rest phase shorter than :func:`short_phase` allows."""
        hours, rpm = info.data.get("hours"), info.data.get("rpm")
        if hours is not None and rpm is not None:
            why = short_phase(hours, rpm, milling)
            if why:
                raise ValueError(why)
        return milling


#: the shortest milling or rest phase a segment's share may leave (s): bmctl.limits.PHASE_MIN_MINUTES
PHASE_MIN_S = PHASE_MIN_MINUTES * 60.0


def short_phase(hours: float, rpm: float, milling: float, piece: str = "segment") -> str:
    """What is wrong with a segment whose milling share leaves a milling or rest phase shorter than
    :data:`PHASE_MIN_S`; empty when nothing is.

    A share of 0 or 1 (and any share of a rest, rpm 0) leaves no second phase and is always fine.

    Parameters
    ----------
    hours : float
        Segment length (h).
    rpm : float
        Its speed (0: a rest).
    milling : float
        The share of ``hours`` spent milling, first.
    piece : str, optional
        What ``hours`` is the length of, as the reason names it (a logged interval: "interval").

    Returns
    -------
    str
        The reason, one line, or "".

    Examples
    --------
    >>> short_phase(0.5, 300.0, 0.5), short_phase(0.5, 300.0, 1.0), short_phase(0.5, 0.0, 0.0001)
    ('', '', '')
    >>> print(short_phase(0.5, 300.0, 0.0001))  # doctest: +NORMALIZE_WHITESPACE
    mills 0.18 s of the segment's 0.5 h, shorter than the 6 s a mill or rest phase lasts at least
    (a share of 0 or 1 leaves none)
    >>> short_phase(0.5, 300.0, 0.99999)[:40]
    "rests 0.018 s of the segment's 0.5 h, sh"
    """
    if rpm <= 0 or not 0.0 < milling < 1.0:
        return ""
    for what, seconds in (("mills", milling * hours * 3600.0), ("rests", (1.0 - milling) * hours * 3600.0)):
        if seconds < PHASE_MIN_S * (1.0 - 1e-9):  # a share that divides the segment exactly at 6 s is kept
            return (f"{what} {seconds:.2g} s of the {piece}'s {hours:g} h, shorter than the {PHASE_MIN_S:g} s a mill "
                    "or rest phase lasts at least (a share of 0 or 1 leaves none)")
    return ""


class ScheduleFile(Strict):
    """A schedule TOML file."""

    name: str = ""
    segment: list[SegmentSpec] = Field(min_length=1)

    @field_validator("segment", mode="after")
    @classmethod
    def _total_within_a_batch(cls, segment: list[SegmentSpec]) -> list[SegmentSpec]:
        """Refuse segments whose hours add up to more than :data:`~bmctl.limits.HOURS_MAX`."""
        why = long_total(sum(s.hours for s in segment))
        if why:
            raise ValueError(why)
        return segment


def long_total(hours: float) -> str:
    """What is wrong with a schedule of ``hours`` in all: longer than :data:`~bmctl.limits.HOURS_MAX`,
    the longest batch; empty when nothing is (a sum rounded within
    :data:`~bmctl.physics.constants.TIME_EPS_H` of it is kept).

    Examples
    --------
    >>> long_total(1000.0)
    ''
    >>> print(long_total(1500.0))
    the segments' hours add up to 1500 h, more than the longest batch (1000 h)
    """
    if hours > HOURS_MAX + TIME_EPS_H:
        return f"the segments' hours add up to {hours:.15g} h, more than the longest batch ({HOURS_MAX:g} h)"
    return ""


#: a length within this of a whole number of minutes is whole (min): a few microseconds
WHOLE_MINUTE_TOL = 1e-7


def is_whole_minutes(hours: float) -> bool:
    """Whether ``hours`` is a whole number of minutes (within :data:`WHOLE_MINUTE_TOL`).

    Parameters
    ----------
    hours : float
        A length (h).

    Examples
    --------
    >>> is_whole_minutes(7 / 60), is_whole_minutes(0.09)
    (True, False)
    """
    m = hours * 60.0
    return abs(m - round(m)) <= WHOLE_MINUTE_TOL


def minutes_text(hours: float) -> str:
    """A length in minutes as a schedule file's comment shows it: whole minutes as such, else with the
    decimals it takes (at most 4, with "≈" beyond), so that the comment never rounds a length to a
    whole minute it is not.

    Parameters
    ----------
    hours : float
        The length (h).

    Examples
    --------
    >>> minutes_text(0.5), minutes_text(0.09), minutes_text(0.08334), minutes_text(0.123456789)
    ('30 min', '5.4 min', '5.0004 min', '≈ 7.4074 min')
    """
    m = hours * 60.0
    if is_whole_minutes(hours):
        return f"{round(m):d} min"
    for k in range(1, 5):
        if abs(round(m, k) - m) <= WHOLE_MINUTE_TOL:
            return f"{m:.{k}f} min"
    return f"≈ {m:.4f} min"


@dataclass(frozen=True)
class Segment:
    """``hours`` long: mill at ``rpm`` for ``milling * hours``, then rest."""

    hours: float
    rpm: float
    milling: float = 1.0


@dataclass(frozen=True)
class Schedule:
    """Segments of (hours, rpm, milling share); see the module.

    Attributes
    ----------
    segments : tuple of Segment
        ``Segment(hours, rpm, milling=1.0)`` in order; rpm 0 is a rest.
    name : str
        A label for reports.

    Examples
    --------
    >>> s = Schedule.from_pairs([(2.0, 300.0), (1.0, 0.0)], name="mill, then rest")
    >>> s.hours, s.pairs()
    (3.0, [(2.0, 300.0), (1.0, 0.0)])
    """

    segments: tuple[Segment, ...]
    name: str = ""

    # --- constructors ---------------------------------------------------------------------------
    @classmethod
    def from_pairs(cls, pairs: Iterable[Sequence[float]], name: str = "") -> "Schedule":
        """From (hours, rpm) or (hours, rpm, milling) tuples."""
        return cls(tuple(Segment(float(p[0]), float(p[1]), float(p[2]) if len(p) > 2 else 1.0) for p in pairs), name)

    @classmethod
    def load(cls, path: str | Path) -> "Schedule":
        """Read a schedule TOML (``[[segment]]`` tables with ``hours``, ``rpm``, optional ``milling``)."""
        f = load(ScheduleFile, path)
        return cls(tuple(Segment(s.hours, s.rpm, s.milling) for s in f.segment), f.name)

    @classmethod
    def from_card(cls, card, hours: float | None = None, rpm: float | None = None) -> "Schedule":
        """The card's recipe (continuous, or ``mill_min``/``rest_min`` cycles), optionally
        overriding its hours and rpm."""
        p = card.process
        total = p.hours if hours is None else hours
        speed = p.rpm if rpm is None else rpm
        if p.mode == "continuous" or rpm is not None and rpm == 0:
            return cls.from_pairs([(total, speed)], card.card.name)
        mill_h, rest_h = p.mill_min / 60.0, p.rest_min / 60.0
        segs: list[tuple[float, float]] = []
        t = 0.0
        while t < total - PIECE_EPS_H:
            m = min(mill_h, total - t)
            segs.append((m, speed))
            t += m
            if t < total - PIECE_EPS_H:
                r = min(rest_h, total - t)
                segs.append((r, 0.0))
                t += r
        return cls.from_pairs(segs, card.card.name)

    @classmethod
    def from_inputs(cls, U, interval_h: float, rpm_decimals: int | None = 0, name: str = "") -> "Schedule":
        """Applied (rpm, milling) per interval -> mill, then rest; equal neighbours merged.

        Parameters
        ----------
        U : array_like, (N, 2)
            Applied (rpm, milling) per interval.
        interval_h : float
            Interval length (h).
        rpm_decimals : int or None, optional
            Rounding of the rpm values (None: none).
        name : str, optional
            Label.
        """
        segs: list[list[float]] = []

        def add(hours, rpm):
            if hours <= PIECE_EPS_H:
                return
            if segs and abs(segs[-1][1] - rpm) < TIME_EPS_H:
                segs[-1][0] += hours
            else:
                segs.append([hours, rpm])

        for rpm, m in np.asarray(U, dtype=float).reshape(-1, 2):
            r = round(float(rpm), rpm_decimals) if rpm_decimals is not None else float(rpm)
            if m <= 0 or r <= 0:
                add(interval_h, 0.0)
            else:
                add(m * interval_h, r)
                add((1 - m) * interval_h, 0.0)
        return cls.from_pairs(segs, name)

    # --- checks ---------------------------------------------------------------------------------
    def check_rpm_max(self, rpm_max: float, where: str) -> None:
        """Refuse a segment faster than the mill's ``rpm_max``, naming the file and segment.

        Parameters
        ----------
        rpm_max : float
            The card's ``mill.rpm_max``.
        where : str
            The schedule file, named first.

        Raises
        ------
        bmctl.errors.InputError
            ``where: segment[i].rpm: R exceeds the mill's rpm_max M``.

        Examples
        --------
        >>> Schedule.from_pairs([(1.0, 300.0)]).check_rpm_max(600.0, "s.toml")
        >>> Schedule.from_pairs([(1.0, 300.0), (1.0, 1500.0)]).check_rpm_max(600.0, "s.toml")
        Traceback (most recent call last):
        ...
        bmctl.errors.InputError: s.toml: segment[1].rpm: 1500 exceeds the mill's rpm_max 600
        """
        from .errors import InputError

        for i, seg in enumerate(self.segments):
            if seg.rpm > rpm_max:
                raise InputError(f"{where}: segment[{i}].rpm: {seg.rpm:g} exceeds the mill's rpm_max {rpm_max:g}")

    # --- views ----------------------------------------------------------------------------------
    @property
    def hours(self) -> float:
        """Total length (h)."""
        return sum(s.hours for s in self.segments)

    def pairs(self) -> list[tuple[float, float]]:
        """(hours, rpm) pieces: each segment's milling piece, then its rest piece (if any)."""
        out = []
        for s in self.segments:
            if s.milling >= 1.0:
                out.append((s.hours, s.rpm))
            elif s.milling <= 0.0 or s.rpm <= 0:
                out.append((s.hours, 0.0))
            else:
                out += [(s.hours * s.milling, s.rpm), (s.hours * (1 - s.milling), 0.0)]
        return out

    def __iter__(self) -> Iterator[tuple[float, float]]:
        return iter(self.pairs())

    def __len__(self) -> int:
        return len(self.pairs())

    def inputs_between(self, t0: float, t1: float) -> list[tuple[float, float, float]]:
        """The (rpm, milling, hours) pieces between batch times t0 and t1 (h).

        Time beyond the end of the schedule is a rest (rpm 0); ``milling`` is 1 for rpm > 0.
        """
        out = []
        start = 0.0
        for h, rpm in self.pairs():
            a, b = max(t0, start), min(t1, start + h)
            if b > a + PIECE_EPS_H:
                out.append((float(rpm), 1.0 if rpm > 0 else 0.0, b - a))
            start += h
        if t1 > max(t0, start) + PIECE_EPS_H:
            out.append((0.0, 0.0, t1 - max(t0, start)))
        return out

    def grid(self, dt_h: float) -> list[tuple[float, float]]:
        """Per-interval (rpm, milling) on a ``dt_h`` grid (each segment a whole number of intervals)."""
        out = []
        for s in self.segments:
            out += [(float(s.rpm), float(s.milling))] * int(round(s.hours / dt_h))
        return out

    def scaled(self, factor: float) -> "Schedule":
        """Every segment's length times ``factor``."""
        return Schedule(tuple(Segment(s.hours * factor, s.rpm, s.milling) for s in self.segments), self.name)

    def toml(self) -> str:
        """TOML text of the schedule (the ``bmctl simulate --schedule`` format)."""
        lines = [f'name = "{self.name}"'] if self.name else []
        for s in self.segments:
            lines += ["", "[[segment]]", f"hours = {s.hours:.10g}   # {minutes_text(s.hours)}", f"rpm = {s.rpm:g}"]
            if s.milling != 1.0:
                lines.append(f"milling = {s.milling:.10g}")
        return "\n".join(lines) + "\n"


def as_schedule(value) -> Schedule:
    """A :class:`Schedule` from a schedule, a config schedule or (hours, rpm) pairs."""
    if isinstance(value, Schedule):
        return value
    if hasattr(value, "segment"):  # bmctl.config.Schedule (pydantic)
        return Schedule.from_pairs([(s.hours, s.rpm) for s in value.segment], value.name)
    return Schedule.from_pairs(value)
