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

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Iterator, Sequence

import numpy as np

# One ``[[segment]]`` table and a schedule file are the classes bmctl.config.load_schedule reads with, so
# that every reader of a schedule file holds it to the same limits (their validators use short_phase
# and long_total below).
from .config import Schedule as ScheduleFile
from .config import Segment as SegmentSpec  # noqa: F401  (bmctl.calibrate.history, the docs)
from .config import card_schedule, load, validate
from .errors import InputError
from .io import loads_toml, toml_string
from .limits import HOURS_MAX, PHASE_MIN_MINUTES, RPM_MAX
from .physics.constants import TIME_EPS_H

#: pieces shorter than this (h) are dropped when a schedule is cut or merged
PIECE_EPS_H = 1e-12


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
        """From (hours, rpm) or (hours, rpm, milling) tuples, held to a schedule file's ranges
        (:func:`checked_segment`, :func:`long_total`).

        Parameters
        ----------
        pairs : iterable of (hours, rpm) or (hours, rpm, milling)
            The segments in order; ``milling`` defaults to 1.
        name : str, optional
            Label.

        Raises
        ------
        bmctl.errors.InputError
            A segment outside the ranges (``segment[i].FIELD: ...``) or a total over
            :data:`~bmctl.limits.HOURS_MAX` (``segment: ...``).

        Examples
        --------
        >>> Schedule.from_pairs([(1.0, 300.0, 2.0)])
        Traceback (most recent call last):
        ...
        bmctl.errors.InputError: segment[0].milling: 2 is outside [0, 1]
        """
        segs = tuple(checked_segment(i, p) for i, p in enumerate(pairs))
        why = long_total(sum(s.hours for s in segs))
        if why:
            raise InputError(f"segment: {why}")
        return cls(segs, name)

    @classmethod
    def load(cls, path: str | Path) -> "Schedule":
        """Read a schedule TOML (``[[segment]]`` tables with ``hours``, ``rpm``, optional ``milling``)."""
        f = load(ScheduleFile, path)
        return cls(tuple(Segment(s.hours, s.rpm, s.milling) for s in f.segment), f.name)

    @classmethod
    def from_card(cls, card, hours: float | None = None, rpm: float | None = None) -> "Schedule":
        """The card's recipe (continuous, or ``mill_min``/``rest_min`` cycles), optionally
        overriding its hours and rpm: :func:`bmctl.config.card_schedule`, with its limits.

        Parameters
        ----------
        card : ModelCard
            Its ``process`` section gives the recipe; its name names the schedule.
        hours : float, optional
            Batch length (h), 1 s to :data:`~bmctl.limits.HOURS_MAX` (default: the card's).
        rpm : float, optional
            Speed, 0 to :data:`~bmctl.limits.RPM_MAX` (default: the card's; 0: one rest).

        Raises
        ------
        bmctl.errors.InputError
            ``hours: -5 h is outside [1 s, 1000 h], the longest batch``; ``rpm: ...`` likewise.
        """
        if rpm is not None and not 0.0 <= rpm <= RPM_MAX:  # NaN too
            raise InputError(f"rpm: {rpm:g} is outside [0, {RPM_MAX:g}] rpm")
        return cls.from_pairs(card_schedule(card, hours, rpm), card.card.name)

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
        try:
            U = np.asarray(U, dtype=float)
        except (TypeError, ValueError):
            raise InputError("U: must be (rpm, milling) numbers per interval") from None
        if U.ndim == 1 and U.size % 2 == 0:  # flat (rpm, milling, rpm, milling, ...), as read before
            U = U.reshape(-1, 2)
        if U.ndim != 2 or U.shape[1] != 2 or not np.all(np.isfinite(U)):
            raise InputError(f"U: must be finite (rpm, milling) per interval, shape (N, 2) (got shape {U.shape})")
        if U.size and (U[:, 0].min() < 0 or not (0 <= U[:, 1].min() and U[:, 1].max() <= 1)):
            raise InputError("U: rpm must be >= 0 and milling in [0, 1] (a share over 1 lengthened the interval)")
        if not (isinstance(interval_h, (int, float, np.floating, np.integer)) and math.isfinite(interval_h)
                and interval_h > 0):
            raise InputError(f"interval_h: must be a finite number > 0 (got {interval_h!r})")
        segs: list[list[float]] = []

        def add(hours, rpm):
            if hours <= PIECE_EPS_H:
                return
            if segs and abs(segs[-1][1] - rpm) < TIME_EPS_H:
                segs[-1][0] += hours
            else:
                segs.append([hours, rpm])

        for rpm, m in U:
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
        """Per-interval (rpm, milling) on a ``dt_h`` grid.

        Meant for schedules whose segments are whole numbers of intervals (the identification
        experiments, :mod:`bmctl.moments.identify`); each such segment gives that many intervals.
        Otherwise every segment boundary is moved to the nearest grid time (a tie to the even
        interval count), so the grid lasts the schedule's hours rounded to whole intervals (at most
        half an interval off in all, not per segment), and a segment that no grid time falls
        within gets no interval: its time goes to its neighbours.

        Parameters
        ----------
        dt_h : float
            Interval length (h), > 0.

        Returns
        -------
        list of (rpm, milling)
            One pair per interval.

        Examples
        --------
        >>> Schedule.from_pairs([(1.0, 300.0, 0.5), (0.5, 0.0)]).grid(0.5)
        [(300.0, 0.5), (300.0, 0.5), (0.0, 1.0)]
        >>> len(Schedule.from_pairs([(0.2, 300.0)] * 5).grid(0.5))  # 1 h: two intervals, not none
        2
        """
        if not dt_h > 0.0:
            raise ValueError(f"grid: the interval must be > 0 h (got {dt_h!r})")
        out: list[tuple[float, float]] = []
        end = 0.0
        for s in self.segments:
            n = int(round((end + s.hours) / dt_h)) - len(out)
            out += [(float(s.rpm), float(s.milling))] * max(n, 0)
            end += s.hours
        return out

    def scaled(self, factor: float) -> "Schedule":
        """Every segment's length times ``factor`` (finite, > 0), held to :meth:`from_pairs`'s limits.

        Examples
        --------
        >>> Schedule.from_pairs([(1.0, 300.0), (0.5, 0.0)]).scaled(2).pairs()
        [(2.0, 300.0), (1.0, 0.0)]
        """
        if isinstance(factor, bool) or not isinstance(factor, (int, float, np.floating, np.integer)) \
                or not (math.isfinite(factor) and factor > 0):
            raise InputError(f"factor: must be a finite number > 0 (got {factor!r})")
        return Schedule.from_pairs([(s.hours * factor, s.rpm, s.milling) for s in self.segments], self.name)

    def toml(self) -> str:
        """TOML text of the schedule (the ``bmctl simulate --schedule`` format) that :meth:`load` reads
        back to the same schedule: numbers as :func:`toml_number` writes them (``hours`` to 10
        significant digits, ``rpm`` as ``%g``, more digits only where those would change the value),
        the name as :func:`bmctl.io.toml_string` quotes it. A schedule that a file cannot hold (a
        piece under a file's shortest segment, 1 s; a share that leaves a phase under 6 s; a name of
        two lines) is refused (:class:`~bmctl.errors.InputError` naming the segment and field)
        rather than written as a file that :meth:`load` would refuse.

        Examples
        --------
        >>> print(Schedule.from_pairs([(0.5, 300.0), (1.0, 1234.56789, 0.75)], name='say "go"').toml())
        name = "say \\"go\\""
        <BLANKLINE>
        [[segment]]
        hours = 0.5   # 30 min
        rpm = 300
        <BLANKLINE>
        [[segment]]
        hours = 1   # 60 min
        rpm = 1234.56789
        milling = 0.75
        <BLANKLINE>
        """
        lines = [f"name = {toml_string(self.name)}"] if self.name else []
        for s in self.segments:
            lines += ["", "[[segment]]", f"hours = {toml_number(s.hours, '.10g')}   # {minutes_text(s.hours)}",
                      f"rpm = {toml_number(s.rpm)}"]
            if s.milling != 1.0:
                lines.append(f"milling = {toml_number(s.milling, '.10g')}")
        text = "\n".join(lines) + "\n"
        # a schedule a file cannot hold (a piece under 1 s, a name of two lines) is refused, not written
        validate(ScheduleFile, loads_toml(text, "toml()"), "Schedule.toml()")
        return text


def checked_segment(i: int, values: Sequence[float]) -> Segment:
    """Segment ``i`` from (hours, rpm) or (hours, rpm, milling), held to the ranges of a schedule
    file's fields (:class:`SegmentSpec`): finite, ``hours`` at most :data:`~bmctl.limits.HOURS_MAX`,
    ``rpm`` within [0, :data:`~bmctl.limits.RPM_MAX`], ``milling`` within [0, 1].

    A piece shorter than a file's 1-s segment, or a share that leaves a phase under 6 s
    (:func:`short_phase`), is kept: a card's recipe cut at the batch end, or a controller's plan,
    can hold one; files and command-line values are refused them where they are read.

    Parameters
    ----------
    i : int
        Its index, as the message names it.
    values : sequence of 2 or 3 floats
        (hours, rpm[, milling]).

    Raises
    ------
    bmctl.errors.InputError
        ``segment[i].FIELD: VALUE is outside [LO, HI]``.

    Examples
    --------
    >>> checked_segment(0, (1.0, 300))
    Segment(hours=1.0, rpm=300.0, milling=1.0)
    >>> checked_segment(2, (-5.0, 300))
    Traceback (most recent call last):
    ...
    bmctl.errors.InputError: segment[2].hours: -5 h is outside [0, 1000 h], the longest batch
    """
    try:
        n = len(values)
        nums = [float(v) for v in values]
    except (TypeError, ValueError):
        raise InputError(f"segment[{i}]: not (hours, rpm[, milling]) numbers: {values!r:.80}") from None
    if n not in (2, 3):
        raise InputError(f"segment[{i}]: give (hours, rpm) or (hours, rpm, milling), not {n} values")
    hours, rpm, milling = nums[0], nums[1], nums[2] if n == 3 else 1.0
    if not 0.0 <= hours <= HOURS_MAX:  # NaN fails every comparison
        raise InputError(f"segment[{i}].hours: {hours:g} h is outside [0, {HOURS_MAX:g} h], the longest batch")
    if not 0.0 <= rpm <= RPM_MAX:
        raise InputError(f"segment[{i}].rpm: {rpm:g} is outside [0, {RPM_MAX:g}] rpm")
    if not 0.0 <= milling <= 1.0:
        raise InputError(f"segment[{i}].milling: {milling:g} is outside [0, 1]")
    return Segment(hours, rpm, milling)


def toml_number(x: float, fmt: str = "g") -> str:
    """``x`` as TOML text that reads back as exactly ``x``: formatted with ``fmt`` where that loses
    nothing (``300``, ``0.5``), else with every digit it takes (``repr``).

    Parameters
    ----------
    x : float
        A finite number.
    fmt : str, optional
        The readable form tried first (a :func:`format` spec).

    Examples
    --------
    >>> toml_number(300.0), toml_number(0.5), toml_number(1234.56789), toml_number(7 / 60, ".10g")
    ('300', '0.5', '1234.56789', '0.11666666666666667')
    """
    x = float(x)
    if not math.isfinite(x):
        raise ValueError(f"a schedule number must be finite (got {x!r})")
    text = format(x, fmt)
    return text if float(text) == x else repr(x)


def as_schedule(value) -> Schedule:
    """A :class:`Schedule` from a schedule, a schedule file's model (:class:`bmctl.config.Schedule`,
    milling shares kept) or (hours, rpm[, milling]) tuples."""
    if isinstance(value, Schedule):
        return value
    if hasattr(value, "segment"):  # bmctl.config.Schedule (pydantic)
        return Schedule.from_pairs([(s.hours, s.rpm, getattr(s, "milling", 1.0)) for s in value.segment], value.name)
    return Schedule.from_pairs(value)
