"""History files: what a mill ran and what was measured at which times.

A history (TOML) names the schedule the mill ran (a schedule file, read as
:meth:`bmctl.schedule.Schedule.load` reads one, or inline ``[[segment]]`` tables; either way
``hours``, ``rpm`` and an optional ``milling`` share, held to a schedule file's limits,
:class:`bmctl.schedule.SegmentSpec`: a share leaves no phase under 6 s, and the hours add up to at
most 1000 h) and the samples taken (``[[sample]]`` with ``t_h`` and either ``table`` = a particle
table CSV or ``image`` = a micrograph measured as ``bmctl measure`` does, with ``um_per_px``). Paths
are relative to the history file and stay inside its folder (:func:`bmctl.io.inside`: an absolute
path or one leading out of the folder is refused, and nothing outside it is read). Every problem is
one line naming the file and the field. An image is measured as ``bmctl measure`` measures it
(:func:`bmctl.measure.micrograph.measure_micrograph`: data bar excluded, automatic speck limit) and
its verdict checked as ``bmctl estimate`` checks it: an ``unusable`` image is refused, a
``doubtful`` one noted in :attr:`History.warnings`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pydantic import Field, field_validator

from .. import io
from ..config import ModelCard, Range, Strict, read_toml, segments_within_a_batch, validate
from ..limits import HOURS_MAX
from ..errors import InputError
from ..schedule import Schedule, SegmentSpec

IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg", ".bmp")
MIN_PARTICLES = 10


class HistorySegment(SegmentSpec):
    """One inline ``[[segment]]``: a schedule file's segment (:class:`bmctl.schedule.SegmentSpec`), held to
    the same limits: ``hours`` 1 s to 1000 h, ``rpm`` within :data:`bmctl.limits.RPM_MAX`, and a ``milling``
    share that leaves no milling or rest phase shorter than 6 s (:func:`bmctl.schedule.short_phase`)."""


class SampleSpec(Strict):
    t_h: Range(0.0, HOURS_MAX)
    table: str | None = None
    image: str | None = None
    um_per_px: Range(1e-4, 1e3) | None = None  # as --um-per-px (bmctl.measure.scale.check_scale)


class HistoryFile(Strict):
    """The TOML schema of a history."""

    name: str = ""
    schedule: str | None = None
    segment: list[HistorySegment] | None = None
    sample: list[SampleSpec] = Field(min_length=1)

    @field_validator("segment", mode="after")
    @classmethod
    def _total_within_a_batch(cls, segment: list[HistorySegment] | None) -> list[HistorySegment] | None:
        """Refuse inline segments whose hours add up to more than a schedule file's may."""
        return segments_within_a_batch(segment)


@dataclass
class MeasuredSample:
    """One measured sample: sizes (um) and aspect ratios at ``t_h``."""

    t_h: float
    s_um: np.ndarray
    r: np.ndarray
    source: str


@dataclass
class History:
    """A run of the mill: (hours, rpm, milling) segments and measured samples in time order."""

    name: str
    path: str
    segments: list[tuple[float, float, float]]
    samples: list[MeasuredSample]
    warnings: list[str] = field(default_factory=list)  # doubtful (or accepted unusable) images
    schedule: str | None = None  # the schedule file it names, if any (an input, as the history and its samples)

    @property
    def times_h(self) -> list[float]:
        return [s.t_h for s in self.samples]


def _read_sample(src: str, spec: SampleSpec, base: Path, k: int,
                 accept_unusable: bool = False) -> tuple[MeasuredSample, list[str]]:
    from ..measure.micrograph import check_verdicts

    where = f"{src}: sample[{k}]"
    if (spec.table is None) == (spec.image is None):
        raise InputError(f"{where}: give exactly one of table or image")
    if spec.table is not None:
        from ..measure.tables import read_table

        if spec.um_per_px is not None:
            raise InputError(f"{where}.um_per_px: only for an image, not a table")
        path = io.inside(base, spec.table, f"{where}.table")
        if not path.is_file():  # a folder, a FIFO, a device or nothing: name the field that names it
            raise InputError(f"{where}.table: {spec.table[:80]!r} is not a regular file in {base}")
        tab = read_table(path)
        name = spec.table
        from ..measure.micrograph import table_reports

        reports = table_reports(path)  # the verdicts bmctl measure wrote beside the table, if any
        field_name = "table"
    else:
        from ..measure.micrograph import measure_micrograph

        path = io.inside(base, spec.image, f"{where}.image")
        if path.suffix.lower() not in IMAGE_SUFFIXES:
            raise InputError(f"{where}.image: {spec.image}: not an image ({', '.join(IMAGE_SUFFIXES)})")
        if not path.is_file():
            raise InputError(f"{where}.image: {spec.image[:80]!r} is not a regular file in {base}")
        if spec.um_per_px is None:
            raise InputError(f"{where}.um_per_px: required for an image (its pixel size in µm)")
        try:
            res = measure_micrograph(str(path), um_per_px=spec.um_per_px)
        except InputError as exc:  # unreadable, uniform, ...: name the history and the field too
            raise InputError(f"{where}.image: {exc}") from None
        tab, reports = res.table, [res.report()]
        name, field_name = spec.image, "image"
    try:
        warns = check_verdicts(reports, accept_unusable, "--accept-unusable")
    except InputError as exc:
        raise InputError(f"{where}.{field_name}: {exc}") from None
    if len(tab) < MIN_PARTICLES:
        raise InputError(f"{where}: {name}: {len(tab)} particles, need at least {MIN_PARTICLES}")
    smp = MeasuredSample(spec.t_h, np.asarray(tab.s_um, float), np.asarray(tab.r, float), str(base / name))
    return smp, [f"{where}.{field_name}: {w}" for w in warns]


def _refuse_a_file_twice(src: str, base: Path, specs) -> None:
    """One line when two samples name one table or image: its particles would be fitted as two samples
    (at two times), counted twice. A path that is bad for another reason is left to :func:`_read_sample`."""
    named: list[tuple[int, str, str, Path]] = []  # (sample index, field, reference, path)
    for k, spec in enumerate(specs):
        if (spec.table is None) == (spec.image is None):
            continue
        field_name, ref = ("table", spec.table) if spec.table is not None else ("image", spec.image)
        try:
            named.append((k, field_name, ref, io.inside(base, ref, f"{src}: sample[{k}].{field_name}")))
        except InputError:
            continue
    pair = io.repeated_file([n[3] for n in named])
    if pair is not None:
        (j, *_), (k, field_name, ref, _) = named[pair[0]], named[pair[1]]
        raise InputError(f"{src}: sample[{k}].{field_name}: {ref[:80]!r} is also sample[{j}]'s file; each "
                         "sample needs its own")


def load_history(path: str | Path, card: ModelCard | None = None, accept_unusable: bool = False) -> History:
    """Load and check a history file.

    Parameters
    ----------
    path : path-like
        The history TOML.
    card : ModelCard, optional
        If given, every rpm must be within the card's ``mill.rpm_max``.
    accept_unusable : bool, optional
        Keep an image whose measurement verdict is ``unusable`` (noted in ``warnings``).

    Returns
    -------
    History

    Raises
    ------
    bmctl.errors.InputError
        One line naming the file and the field.
    """
    src = str(path)
    base = Path(path).parent
    h = validate(HistoryFile, read_toml(path), src)
    if (h.schedule is None) == (h.segment is None):
        raise InputError(f"{src}: schedule: give exactly one of schedule = \"FILE.toml\" or [[segment]] tables")
    if h.schedule is not None:
        sched = Schedule.load(io.inside(base, h.schedule, f"{src}: schedule"))  # a schedule file's limits
        segments = [(s.hours, s.rpm, s.milling) for s in sched.segments]
        seg_src = f"{base / h.schedule}: segment"
        sched_path = str(base / h.schedule)
    else:
        if not h.segment:
            raise InputError(f"{src}: segment: at least one [[segment]] is needed")
        segments = [(s.hours, s.rpm, s.milling) for s in h.segment]
        seg_src = f"{src}: segment"
        sched_path = None
    if card is not None:
        for i, (_, rpm, _) in enumerate(segments):
            if rpm > card.mill.rpm_max:
                raise InputError(f"{seg_src}[{i}].rpm: {rpm:g} exceeds the mill's rpm_max {card.mill.rpm_max:g}")
    total = sum(s[0] for s in segments)
    times = [s.t_h for s in h.sample]
    for k, (a, b) in enumerate(zip(times, times[1:])):
        if b <= a:
            raise InputError(f"{src}: sample[{k + 1}].t_h: sample times must increase (got {a:g} then {b:g})")
    if times[-1] > total + 1e-9:
        raise InputError(f"{src}: sample[{len(times) - 1}].t_h: {times[-1]:g} h is after the schedule's end ({total:g} h)")
    _refuse_a_file_twice(src, base, h.sample)  # before any table is read or image measured
    read = [_read_sample(src, spec, base, k, accept_unusable) for k, spec in enumerate(h.sample)]
    return History(h.name or Path(path).stem, src, segments, [r[0] for r in read], [w for r in read for w in r[1]],
                   sched_path)


def size_range_warnings(card: ModelCard, samples) -> list[str]:
    """One line per sample whose mean size lies outside the card's range of validity
    (:func:`bmctl.cards.validity`, as ``bmctl simulate`` warns for a run): the model does not hold
    there, and a table in mm or nm read as µm lands there.

    Parameters
    ----------
    card : ModelCard
    samples : iterable of (source, t_h, s_um)
    """
    from ..cards import size_range

    lo, hi = size_range(card)
    out = []
    for source, t_h, s_um in samples:
        m = float(np.mean(s_um))
        if not lo <= m <= hi:
            out.append(f"{source}: mean size {m:.3g} µm at {t_h:g} h is outside the card's [{lo:g}, {hi:g}] µm: "
                       "the model does not hold there (sizes in another unit?)")
    return out
