"""Per-particle tables: area, perimeter, size s (eqn 1) and aspect ratio r (eqn 3), in micrometres.

A particle table CSV has a header and one row per particle, either with columns
``area_um2,perimeter_um`` (s and r are derived; extra columns, ``r`` too, are ignored, and an
``s_um`` beside them must agree with the area's size) or with columns ``s_um,r`` (area and
perimeter are derived). Tables are written with the four columns ``area_um2,perimeter_um,s_um,r``, by ``bmctl measure`` preceded by
``particle_id,image,x_um,y_um`` (the centroid); readers accept both layouts.

Isoperimetric bound: every closed curve of area A has L >= 2 sqrt(pi A) = pi s, i.e.
r >= 0. A measured perimeter a little below the bound (estimator noise on small, round
particles) is raised to it (r = 0); one more than ``ISOPERIMETRIC_TOL`` below it is an error.
"""

from __future__ import annotations

import csv
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError, quote
from ..naming import arg
from ..io import write_csv
from ..plant.events import aspect_from_perimeter, perimeter_from_aspect, size_from_area

COLUMNS = ("area_um2", "perimeter_um", "s_um", "r")
#: how far a table's s_um may lie from its area_um2's size (relative): the six digits measure writes, and more
SIZE_COLUMNS_RTOL = 1e-3
LOCATION_COLUMNS = ("particle_id", "image", "x_um", "y_um")  # written first by `bmctl measure`
ISOPERIMETRIC_TOL = 0.05  # relative shortfall of L below pi s accepted (and raised to pi s)
#: physical range of a particle size: 1 nm to 10 mm (a powder particle outside it is a unit or scale error)
S_MIN_UM, S_MAX_UM = 1e-3, 1e4

#: the largest particle table read (a million particles as `s_um,r` take ~20 MB)
TABLE_MAX_BYTES = 64 << 20


@dataclass(frozen=True)
class ParticleTable:
    """Measured particles: four aligned 1-D float arrays, lengths in micrometres.

    Attributes
    ----------
    area_um2 : ndarray
        Section area A.
    perimeter_um : ndarray
        Boundary length L (>= pi s).
    s_um : ndarray
        Size s = 2 sqrt(A / pi) (eqn 1).
    r : ndarray
        Aspect ratio r = 1 - pi s / L (eqn 3), in [0, 1).

    Examples
    --------
    >>> t = ParticleTable.from_size_aspect([10.0, 20.0], [0.0, 0.1])
    >>> len(t), round(float(t.perimeter_um[1]), 3)
    (2, 69.813)
    """

    area_um2: np.ndarray
    perimeter_um: np.ndarray
    s_um: np.ndarray
    r: np.ndarray

    def __post_init__(self):
        n = None
        for name in COLUMNS:
            v = np.atleast_1d(np.asarray(getattr(self, name), dtype=float)).ravel()
            if n is not None and v.size != n:
                raise ValueError(f"ParticleTable: column {name} has {v.size} rows, expected {n}")
            n = v.size
            object.__setattr__(self, name, v)

    @classmethod
    def from_area_perimeter(cls, area_um2, perimeter_um) -> "ParticleTable":
        """Table from areas and perimeters; perimeters below pi s are raised to pi s (r = 0).

        Parameters
        ----------
        area_um2, perimeter_um : array_like
            Positive areas and perimeters.

        Returns
        -------
        ParticleTable
        """
        area = np.atleast_1d(np.asarray(area_um2, dtype=float))
        s = size_from_area(area)
        perim = np.maximum(np.atleast_1d(np.asarray(perimeter_um, dtype=float)), np.pi * s)
        return cls(area, perim, s, aspect_from_perimeter(s, perim))

    @classmethod
    def from_size_aspect(cls, s_um, r) -> "ParticleTable":
        """Table from sizes and aspect ratios: A = pi s^2 / 4, L = pi s / (1 - r)."""
        s = np.atleast_1d(np.asarray(s_um, dtype=float))
        r = np.broadcast_to(np.asarray(r, dtype=float), s.shape)
        return cls(np.pi * s**2 / 4.0, perimeter_from_aspect(s, r), s, r)

    @classmethod
    def empty(cls) -> "ParticleTable":
        """A table with no particles."""
        return cls(*(np.empty(0) for _ in COLUMNS))

    def __len__(self) -> int:
        return self.s_um.size

    def take(self, index) -> "ParticleTable":
        """Rows selected by an index array or boolean mask."""
        return ParticleTable(*(getattr(self, c)[index] for c in COLUMNS))

    @staticmethod
    def concat(tables) -> "ParticleTable":
        """Rows of several tables, in order."""
        tables = list(tables)
        if not tables:
            return ParticleTable.empty()
        return ParticleTable(*(np.concatenate([getattr(t, c) for t in tables]) for c in COLUMNS))

    def rows(self):
        """Iterate over rows as tuples (area_um2, perimeter_um, s_um, r)."""
        return zip(*(getattr(self, c).tolist() for c in COLUMNS))

    def summary(self) -> dict[str, float]:
        """Count, median s (um) and median r."""
        n = len(self)
        return {
            "count": n,
            "s_median_um": float(np.median(self.s_um)) if n else float("nan"),
            "r_median": float(np.median(self.r)) if n else float("nan"),
        }


def _parse(path: str, lineno: int, col: str, text: str) -> float:
    try:
        if "_" in text:  # Python reads "4_0" as 40: not a number a table means
            raise ValueError
        v = float(text)
    except ValueError:
        raise InputError(f"{path}: row {lineno}, column {col}: not a number ({text!r})") from None
    if not np.isfinite(v):
        raise InputError(f"{path}: row {lineno}, column {col}: must be finite (got {text.strip()})")
    return v


def read_table(path: str | os.PathLike) -> ParticleTable:
    """Read a particle table CSV (``area_um2,perimeter_um`` or ``s_um,r`` columns).

    Row numbers in error messages are file line numbers (the header is line 1); blank lines
    and lines starting with ``#`` are skipped.

    Parameters
    ----------
    path : path-like

    Returns
    -------
    ParticleTable

    Raises
    ------
    bmctl.errors.InputError
        Missing or unreadable file, no header or no rows, missing columns, a value that is
        not a finite number, area/perimeter/s <= 0, r outside [0, 1), or a perimeter more
        than ``ISOPERIMETRIC_TOL`` below pi s.

    Examples
    --------
    >>> import pathlib, tempfile
    >>> f = pathlib.Path(tempfile.mkdtemp()) / "t.csv"
    >>> _ = f.write_text("s_um,r\\n40.0,0.02\\n55.5,0.10\\n", encoding="utf-8")
    >>> t = read_table(f)
    >>> len(t), t.s_um.tolist()
    (2, [40.0, 55.5])
    """
    return _parse_table(str(path), _table_text(path))


def read_table_with_locations(path: str | os.PathLike) -> tuple[ParticleTable, tuple | None]:
    """The particle table (:func:`read_table`) and its rows' images and centroids
    (:func:`read_locations`, None for a table without them) from one read of the file: a table
    replaced between two reads cannot give one's particles the other's locations.

    Parameters
    ----------
    path : path-like

    Returns
    -------
    (ParticleTable, (images, x_um, y_um) or None)

    Examples
    --------
    >>> import pathlib, tempfile
    >>> f = pathlib.Path(tempfile.mkdtemp()) / "t.csv"
    >>> _ = f.write_text("image,x_um,y_um,s_um,r\\na.png,1.5,2.0,40.0,0.02\\n", encoding="utf-8")
    >>> t, (images, x_um, y_um) = read_table_with_locations(f)
    >>> len(t), images, x_um.tolist()
    (1, ['a.png'], [1.5])
    """
    text = _table_text(path)
    table = _parse_table(str(path), text)
    return table, _locations(path, text, len(table))


def _table_text(path) -> str:
    """A particle table's text (a regular file of a sane size), or :class:`InputError` naming it."""
    p = str(path)
    try:
        from ..io import read_input_bytes  # a regular file of a sane size (no FIFO, no device)

        return read_input_bytes(path, max_bytes=TABLE_MAX_BYTES).decode("utf-8-sig")
    except FileNotFoundError:
        raise InputError(f"{p}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{p}: cannot read particle table ({type(exc).__name__})") from None


def _parse_table(p: str, text: str) -> ParticleTable:
    """The particle table in ``text`` (the file ``p``'s), as :func:`read_table` checks it."""
    lines = [(i + 1, ln) for i, ln in enumerate(text.splitlines()) if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise InputError(f"{p}: empty particle table (no header, no rows)")
    reader = csv.reader([ln for _, ln in lines])
    header = [h.strip() for h in next(reader)]
    twice = sorted({h for h in header if h and header.count(h) > 1})
    if twice:
        raise InputError(f"{p}: column {quote(twice[0])} appears twice in the header (which one holds the data?)")
    if {"area_um2", "perimeter_um"} <= set(header):
        cols = ("area_um2", "perimeter_um")
    elif {"s_um", "r"} <= set(header):
        cols = ("s_um", "r")
    else:
        raise InputError(f"{p}: missing columns: need area_um2,perimeter_um or s_um,r (header has {quote(','.join(header))})")
    idx = [header.index(c) for c in cols]
    # s_um beside area_um2 (the four columns measure writes): read from the area, so it must agree with it
    also_s = header.index("s_um") if cols[0] == "area_um2" and "s_um" in header else None
    vals = []
    for (lineno, _), row in zip(lines[1:], reader):
        if len(row) != len(header) and not (len(row) > len(header) and not "".join(row[len(header):]).strip()):
            raise InputError(f"{p}: row {lineno}: {len(row)} fields, header has {len(header)}")
        a, b = (_parse(p, lineno, c, row[j]) for c, j in zip(cols, idx))
        if a <= 0:
            raise InputError(f"{p}: row {lineno}, column {cols[0]}: must be > 0 (got {a:g})")
        s_um = a if cols[0] == "s_um" else float(size_from_area(a))
        if also_s is not None and row[also_s].strip():
            given = _parse(p, lineno, "s_um", row[also_s])
            if not abs(given - s_um) <= SIZE_COLUMNS_RTOL * s_um:
                raise InputError(f"{p}: row {lineno}, column s_um: {given:g} µm disagrees with area_um2's s = "
                                 f"2 sqrt(A/pi) = {s_um:.6g} µm (eqn 1); the size is read from the area: drop "
                                 f"s_um, or give s_um,r alone")
        if not S_MIN_UM <= s_um <= S_MAX_UM:
            got = f"{a:g}" if cols[0] == "s_um" else f"{a:g} µm², s = {s_um:.3g} µm"
            raise InputError(f"{p}: row {lineno}, column {cols[0]}: size outside the physical range "
                             f"[{S_MIN_UM:g}, {S_MAX_UM:g}] µm, 1 nm to 10 mm (got {got})")
        if cols[1] == "r" and not 0.0 <= b < 1.0:
            raise InputError(f"{p}: row {lineno}, column r: must be in [0, 1) (got {b:g})")
        if cols[1] == "perimeter_um":
            if b <= 0:
                raise InputError(f"{p}: row {lineno}, column perimeter_um: must be > 0 (got {b:g})")
            bound = np.pi * float(size_from_area(a))
            if b < (1.0 - ISOPERIMETRIC_TOL) * bound:
                raise InputError(
                    f"{p}: row {lineno}, column perimeter_um: {b:g} is below the isoperimetric bound "
                    f"pi*s = {bound:.6g} (r = {1 - bound / b:.3g} < 0)"
                )
            if not 1.0 - bound / b < 1.0:
                raise InputError(f"{p}: row {lineno}, column perimeter_um: {b:g} is so long for its area that "
                                 f"r = 1 - pi s / L rounds to 1 (r must be < 1)")
        vals.append((a, b))
    if not vals:
        raise InputError(f"{p}: empty particle table (header but no rows)")
    arr = np.array(vals, dtype=float)
    if cols == ("s_um", "r"):
        return ParticleTable.from_size_aspect(arr[:, 0], arr[:, 1])
    return ParticleTable.from_area_perimeter(arr[:, 0], arr[:, 1])


def read_locations(path: str | os.PathLike, n: int) -> tuple[list[str], np.ndarray, np.ndarray] | None:
    """``(images, x_um, y_um)`` per row of a particle table with the columns ``bmctl measure``
    writes before the particles' (``image``, ``x_um``, ``y_um``, :data:`LOCATION_COLUMNS`;
    rows as :func:`read_table` reads them), or None for a table with none of
    them. An empty image is the table's path; an empty or unreadable centroid is NaN (stored NULL)."""
    from ..io import read_input_bytes

    return _locations(path, read_input_bytes(path, max_bytes=TABLE_MAX_BYTES).decode("utf-8-sig"), n)


def _locations(path, text: str, n: int) -> tuple[list[str], np.ndarray, np.ndarray] | None:
    """:func:`read_locations` of the table's ``text``."""
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    rows = list(csv.reader(lines))
    header = [h.strip() for h in rows[0]]
    if not {"image", "x_um", "y_um"} & set(header) or len(rows) - 1 != n:
        return None

    def col(key, conv, missing):
        if key not in header:
            return [missing] * n
        j = header.index(key)
        return [conv(r[j].strip()) if j < len(r) and r[j].strip() else missing for r in rows[1:]]

    def num(v: str) -> float:
        try:
            return float(v)
        except ValueError:
            return math.nan

    return (col("image", str, str(path)), np.array(col("x_um", num, math.nan), dtype=float),
            np.array(col("y_um", num, math.nan), dtype=float))


def check_table(table: ParticleTable, source: str) -> ParticleTable:
    """Refuse a table with a row outside the physical bounds :func:`read_table` enforces
    (s in [S_MIN_UM, S_MAX_UM], 0 <= r < 1, everything finite); returns it.

    Parameters
    ----------
    table : ParticleTable
    source : str
        The input the table came from (named in the message).
    """
    for name in COLUMNS:
        v = getattr(table, name)
        bad = ~np.isfinite(v) | (v <= 0 if name != "r" else ~((v >= 0) & (v < 1)))
        if name == "s_um":
            bad |= ~((v >= S_MIN_UM) & (v <= S_MAX_UM))
        if np.any(bad):
            k = int(np.argmax(bad))
            rng = {"s_um": f"[{S_MIN_UM:g}, {S_MAX_UM:g}] µm", "r": "[0, 1)"}.get(name, "> 0")
            raise InputError(f"{source}: particle {k + 1}: {name} = {v[k]:.4g} outside {rng}: check the scale "
                             f"({arg('um_per_px')}, {arg('scale_bar_um')})")
    return table


@dataclass(frozen=True)
class ParticleLocations:
    """Where each measured particle is: id, source image and centroid (um from the image's
    top-left corner; NaN for particles that came from a table).

    Attributes
    ----------
    particle_id : ndarray of int
    image : tuple of str
    x_um, y_um : ndarray of float
    """

    particle_id: np.ndarray
    image: tuple
    x_um: np.ndarray
    y_um: np.ndarray

    def rows(self):
        """Iterate over rows (particle_id, image, x_um, y_um); NaN centroids are written empty."""
        for k, name, x, y in zip(self.particle_id.tolist(), self.image, self.x_um.tolist(), self.y_um.tolist()):
            yield (int(k), name, x if np.isfinite(x) else "", y if np.isfinite(y) else "")


def write_table(path: str | os.PathLike, table: ParticleTable, locations: ParticleLocations | None = None) -> None:
    """Write the table atomically (:func:`bmctl.io.write_csv`).

    Columns ``area_um2,perimeter_um,s_um,r``, preceded by ``particle_id,image,x_um,y_um``
    when ``locations`` is given. :func:`read_table` reads both layouts.

    Parameters
    ----------
    path : path-like
    table : ParticleTable
    locations : ParticleLocations, optional
        One entry per row of ``table``.

    Raises
    ------
    bmctl.errors.InputError
        A row :func:`read_table` would refuse (not finite, s or r out of range): nothing is written.
    """
    check_table(table, f"write_table: {os.fspath(path)}")  # never a file its own reader refuses
    if locations is None:
        write_csv(path, COLUMNS, table.rows(), fmt="{:.7g}")
        return
    if len(locations.particle_id) != len(table):
        raise ValueError("write_table: locations and table differ in length")
    rows = (tuple(a) + tuple(b) for a, b in zip(locations.rows(), table.rows()))
    write_csv(path, LOCATION_COLUMNS + COLUMNS, rows, fmt="{:.7g}")
