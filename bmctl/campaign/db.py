"""The campaign database: one SQLite file (``DIR/campaign.sqlite``), WAL mode, one transaction per verb.

Tables (schema version :data:`SCHEMA_VERSION`; a version-1 campaign, written before ``sample_inputs``,
is read as it is and upgraded by its next ``sample``, :func:`upgrade`)::

    schema_version(version)
    meta(key, value)                  JSON values: inputs, target, batch hours, seed, ...
    actions(id, t0_h, t1_h, hours, rpm, milling, plan_id, deviation, logged_at)
    temperatures(id, t_h, temperature_c, action_id, logged_at)
    samples(id, t_h, sources, um_per_px, n, s_median_um, r_median, report, logged_at)
    particles(sample_id, particle_id, image, x_um, y_um, area_um2, perimeter_um, s_um, r)
    sample_inputs(sample_id, position, source, sha256)   each image or table of a sample, by its bytes
    estimator_states(id, t_h, state, estimate, created_at)   t_h = -1: the prior, before anything
    plans(id, t_h, rpm, milling, interval_h, advice, controller_state, advise_ms, created_at)
    decisions(id, plan_id, accepted, rpm, milling, note, created_at)

States are plain data (:func:`pack` / :func:`unpack`): one ``.npz`` image written with
``numpy.savez`` and read with ``allow_pickle=False`` (the layout of :mod:`bmctl.checkpoint`).

Concurrency: every verb runs in :func:`transaction`, which opens ``BEGIN IMMEDIATE`` (the
write lock) before reading anything; a second command on the same campaign waits up to
:data:`LOCK_TIMEOUT_S` and is then refused with one line. Read-only verbs use a deferred
transaction, a consistent snapshot under WAL. A process killed mid-verb leaves the database
as of the last commit (SQLite's journal).
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import errno
import hashlib
import io
import json
import math
import os
import sqlite3
import stat
from pathlib import Path
from typing import Annotated

import numpy as np
from pydantic import BaseModel, ConfigDict, StrictBool, StringConstraints

from .. import io as bio
from ..config import Range
from ..checkpoint import ARRAY_TAG, JSON_KEY, _join, _split
from ..errors import InputError

DB_NAME = "campaign.sqlite"
#: the folder of a campaign that holds the copies of its inputs
INPUTS = "inputs"
SCHEMA_VERSION = 2
#: the schema versions this bmctl reads: version 1 lacks ``sample_inputs`` (:data:`SCHEMA_V2`)
READ_VERSIONS = (1, 2)
#: seconds a command waits for another command on the same campaign before it is refused
LOCK_TIMEOUT_S = 30.0

SCHEMA = """
CREATE TABLE schema_version (version INTEGER NOT NULL);
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE actions (
    id INTEGER PRIMARY KEY, t0_h REAL NOT NULL, t1_h REAL NOT NULL, hours REAL NOT NULL, rpm REAL NOT NULL,
    milling REAL NOT NULL, plan_id INTEGER REFERENCES plans(id), deviation TEXT NOT NULL DEFAULT '',
    logged_at TEXT NOT NULL, CHECK (t1_h > t0_h), CHECK (milling >= 0 AND milling <= 1), CHECK (rpm >= 0));
CREATE TABLE temperatures (
    id INTEGER PRIMARY KEY, t_h REAL NOT NULL, temperature_c REAL NOT NULL,
    action_id INTEGER REFERENCES actions(id), logged_at TEXT NOT NULL);
CREATE TABLE samples (
    id INTEGER PRIMARY KEY, t_h REAL NOT NULL, sources TEXT NOT NULL, um_per_px REAL, n INTEGER NOT NULL,
    s_median_um REAL NOT NULL, r_median REAL NOT NULL, report TEXT NOT NULL, logged_at TEXT NOT NULL);
CREATE TABLE particles (
    sample_id INTEGER NOT NULL REFERENCES samples(id), particle_id INTEGER NOT NULL, image TEXT NOT NULL,
    x_um REAL, y_um REAL, area_um2 REAL NOT NULL, perimeter_um REAL NOT NULL, s_um REAL NOT NULL,
    r REAL NOT NULL, PRIMARY KEY (sample_id, particle_id));
CREATE TABLE estimator_states (
    id INTEGER PRIMARY KEY, t_h REAL NOT NULL, state BLOB NOT NULL, estimate TEXT NOT NULL,
    created_at TEXT NOT NULL);
CREATE TABLE plans (
    id INTEGER PRIMARY KEY, t_h REAL NOT NULL, rpm REAL NOT NULL, milling REAL NOT NULL,
    interval_h REAL NOT NULL, advice TEXT NOT NULL, controller_state BLOB NOT NULL, advise_ms REAL NOT NULL,
    created_at TEXT NOT NULL);
CREATE TABLE decisions (
    id INTEGER PRIMARY KEY, plan_id INTEGER NOT NULL REFERENCES plans(id), accepted INTEGER NOT NULL,
    rpm REAL, milling REAL, note TEXT NOT NULL DEFAULT '', created_at TEXT NOT NULL);
CREATE INDEX particles_by_sample ON particles(sample_id);
CREATE INDEX states_by_time ON estimator_states(t_h);
"""
#: what version 2 adds to version 1: the SHA-256 of each input of a sample (the file's bytes, or a
#: table's columns given in memory), so that an input entered again is refused (``sample``)
SCHEMA_V2 = """
CREATE TABLE sample_inputs (
    sample_id INTEGER NOT NULL REFERENCES samples(id), position INTEGER NOT NULL, source TEXT NOT NULL,
    sha256 TEXT NOT NULL, PRIMARY KEY (sample_id, position));
CREATE INDEX sample_inputs_by_sha256 ON sample_inputs(sha256);
"""
SCHEMA = SCHEMA + SCHEMA_V2
#: the tables a version-1 campaign does not have
V2_TABLES = ("sample_inputs",)


def now() -> str:
    """UTC time stamp (ISO 8601, seconds)."""
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def db_path(folder: str | Path) -> Path:
    """The database file of a campaign folder."""
    return Path(folder) / DB_NAME


def _connect(path: Path) -> sqlite3.Connection:
    """A read-write connection. It writes nothing by itself: the journal mode is left as the file
    has it (a verb that records sets WAL after its commit, :func:`transaction`), so that a file
    opened and then refused (another application's database) or only read is left as it was."""
    con = sqlite3.connect(str(path), timeout=LOCK_TIMEOUT_S, isolation_level=None)
    con.execute("PRAGMA synchronous=FULL")
    con.execute("PRAGMA foreign_keys=ON")
    con.execute(f"PRAGMA busy_timeout={int(LOCK_TIMEOUT_S * 1000)}")
    return con


#: what SQLite keeps beside a database: the write-ahead log and its index, the rollback journal
SIDECARS = ("-wal", "-shm", "-journal")


def _sidecars(path: Path) -> list[Path]:
    return [path.with_name(path.name + x) for x in SIDECARS]


def remove_made(path: Path) -> None:
    """Remove a database this process made (a failed ``init``) and the journal files beside it:
    regular files only (a symlink or folder in their place is the user's)."""
    for p in [path] + _sidecars(path):
        if p.is_file() and not p.is_symlink():
            with contextlib.suppress(OSError):
                p.unlink()


def _kind(p: Path) -> str:
    """What is at ``p`` (which exists), in words."""
    if p.is_symlink():
        return "a symlink"
    return "a folder" if p.is_dir() else "a file" if p.is_file() else "not a regular file"


def create(folder: str | Path, made: list | None = None) -> sqlite3.Connection:
    """Create a new campaign database (refused when ``folder`` already holds one, or when a file or
    folder is where SQLite keeps its journal). Nothing is made before a refusal; what it made is
    removed when it fails (the database file is appended to ``made`` as soon as it exists, for
    the caller to remove should it fail later)."""
    folder = Path(folder)
    path = db_path(folder)
    taken = InputError(f"{folder}: already holds a campaign ({path.name}); choose another folder")
    if folder.exists() and not folder.is_dir():
        raise InputError(f"{folder}: is a file, not a folder (campaign init makes a campaign folder)")
    if os.path.lexists(path):
        if path.is_dir() or not path.exists():  # a folder, a symlink that cannot be resolved
            raise InputError(f"{path}: is in the way ({_kind(path)}); campaign init makes its database there")
        raise taken
    for side in _sidecars(path):
        if os.path.lexists(side):
            raise InputError(f"{side}: is in the way ({_kind(side)}): SQLite keeps the journal of {path.name} there; "
                             "move it or choose another folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{folder}: cannot make the campaign folder ({exc.strerror or exc})") from None
    # The file is made here, not by SQLite (which makes it 0644 whatever the umask; its -wal and
    # -shm files take the database's mode): the user's umask decides, as for every output. O_EXCL:
    # of two `init`s on one folder at once, one starts the campaign, the other is refused.
    try:
        os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
    except FileExistsError:
        raise taken from None
    except OSError as exc:
        raise InputError(f"{path}: cannot be made ({exc.strerror or exc})") from None
    if made is not None:
        made.append(path)
    try:
        return _connect(path)
    except BaseException:  # Ctrl-C, a file SQLite cannot open: no half-made database is left behind
        remove_made(path)
        raise


def _wal_mode(path: Path) -> bool:
    """Whether the SQLite file is in WAL mode (its header's read/write versions, bytes 18-19, are 2)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(100)
    except OSError:
        return False
    return head[:16] == b"SQLite format 3\x00" and len(head) >= 20 and 2 in (head[18], head[19])


def _busy(exc: Exception) -> bool:
    return "locked" in str(exc) or "busy" in str(exc)


def _disk_full(path: Path) -> bool:
    """Whether the file system that holds ``path`` has no room left (a read of a write-ahead-log
    database then fails with SQLite's "disk I/O error")."""
    try:
        st = os.statvfs(path.parent)
    except (OSError, AttributeError):  # no statvfs (Windows), or the folder went away
        return False
    return st.f_bavail * st.f_frsize < 64 * 1024


def _connect_read_only(path: Path, fallback: bool = True) -> sqlite3.Connection:
    """A read-only connection (``mode=ro``), for a campaign the user may not write (an archive, a
    share mounted read-only) and to recognise a file before anything writes to it; ``immutable``
    where SQLite would otherwise make a write-ahead log and its index beside a WAL-mode file that
    nobody has open (a read-only connection cannot remove them again: they were left behind, with
    the database's mode), or where it cannot even keep its shared-memory file beside it (nobody can
    write it then either). ``immutable`` reads the database file alone: a write-ahead log beside
    it (commits not yet copied into the file) is refused, not left out; so is a rollback journal
    of a transaction that did not finish (SQLite must roll it back first). ``fallback`` False (a
    campaign the user may write): SQLite's error is raised as it is."""
    from urllib.parse import quote

    real = path.resolve()
    uri = f"file:{quote(str(real))}?mode=ro"
    wal, shm, journal = _sidecars(real)
    if _wal_mode(real) and not os.path.lexists(wal) and not os.path.lexists(shm):
        # every connection to a WAL-mode file keeps its log open: none has, and no log is left
        return sqlite3.connect(uri + "&immutable=1", uri=True, timeout=LOCK_TIMEOUT_S, isolation_level=None)
    try:
        con = sqlite3.connect(uri, uri=True, timeout=LOCK_TIMEOUT_S, isolation_level=None)
        con.execute("SELECT COUNT(*) FROM sqlite_master").fetchone()
        return con
    except sqlite3.OperationalError as exc:
        if _busy(exc) or not fallback:
            raise
        if getattr(exc, "sqlite_errorname", "") == "SQLITE_READONLY_ROLLBACK" or journal.is_file() \
                and journal.stat().st_size > 0:
            raise InputError(f"{path}: its rollback journal {journal.name} holds a transaction that did not finish; "
                             "SQLite rolls it back only where this user may write the campaign") from None
        if wal.is_file() and wal.stat().st_size > 0:
            raise InputError(f"{path}: its write-ahead log {wal.name} holds commits SQLite cannot read in a folder "
                             "this user may not write; read a copy of the campaign folder in one you may write") from None
        return sqlite3.connect(uri + "&immutable=1", uri=True, timeout=LOCK_TIMEOUT_S, isolation_level=None)


def _refuse_unusable(folder: Path, path: Path) -> None:
    """Refuse what is not a database file at ``path`` (missing, a folder, a symlink that cannot be
    resolved, not a regular file, empty) or a folder where SQLite keeps its journal, each in one line,
    before SQLite opens anything."""
    try:
        os.lstat(path)
    except FileNotFoundError:
        raise InputError(f"{folder}: no campaign here ({path.name} not found; start one with "
                         "`bmctl campaign init`)") from None
    except NotADirectoryError:
        raise InputError(f"{folder}: is a file, not a campaign folder") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    try:
        st = os.stat(path)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise InputError(f"{path}: is a symlink loop (it cannot be resolved), not a campaign database") from None
        if exc.errno == errno.ENOENT:
            raise InputError(f"{path}: is a symlink to {os.readlink(path)!r}, which does not exist") from None
        raise InputError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if stat.S_ISDIR(st.st_mode):
        raise InputError(f"{path}: is a folder, not a campaign database")
    if not stat.S_ISREG(st.st_mode):
        raise InputError(f"{path}: not a regular file, not a campaign database")
    real = path.resolve()
    wal = _sidecars(real)[0]
    if st.st_size == 0 and not (wal.is_file() and wal.stat().st_size):
        # refused before SQLite opens it: opening would write a header into the user's file
        raise InputError(f"{path}: empty (0 bytes), not a campaign database (a `campaign init` that did not "
                         "finish, or a damaged copy)")
    for side in _sidecars(real):
        if os.path.lexists(side) and _kind(side) != "a file":
            raise InputError(f"{side}: is in the way ({_kind(side)}): SQLite keeps the journal of {path.name} "
                             "there; move it")


def _not_writable(path: Path) -> Path | None:
    """The first of the database, its folder and the journal files beside it that this user may
    not write (SQLite needs them all to record), or None."""
    real = path.resolve()
    # named as the user gave them, where the database is no symlink into another folder
    base = path.parent if real.parent == path.parent.resolve() else real.parent
    if not os.access(real, os.W_OK):
        return path
    if not os.access(real.parent, os.W_OK | os.X_OK):
        return base
    for side in _sidecars(real):
        if os.path.lexists(side) and not os.access(side, os.W_OK):
            return base / side.name
    return None


def _read_only(p: Path) -> InputError:
    where = "" if p.name.startswith(DB_NAME) else f" (SQLite keeps the journal of {DB_NAME} in this folder)"
    return InputError(f"{p}: read-only for this user{where}: this command records to the campaign "
                      "(`status` and `report` read it as it is)")


def refuse_read_only(folder: str | Path) -> None:
    """Refuse, before any work, a verb that records to a campaign whose database this user may not
    write (or that is no database file): what :func:`open_db` refuses first, for a verb with work
    to do before it opens the campaign (``sample`` measures its images)."""
    folder = Path(folder)
    path = db_path(folder)
    _refuse_unusable(folder, path)
    blocked = _not_writable(path)
    if blocked is not None:
        raise _read_only(blocked)


def _version_row(con: sqlite3.Connection):
    return con.execute("SELECT version FROM schema_version").fetchone()


def _check_version(path: Path, row) -> None:
    if row is None:
        raise InputError(f"{path}: schema_version: empty (damaged, or not a bmctl campaign database)")
    if not isinstance(row[0], int) or isinstance(row[0], bool):
        raise InputError(f"{path}: schema_version {str(row[0])[:40]!r}: not an integer (damaged or edited)")
    if not _known_version(row[0]):
        raise InputError(f"{path}: campaign schema version {row[0]}, this bmctl reads "
                         f"{' and '.join(map(str, READ_VERSIONS))}")


def open_db(folder: str | Path, read_only: bool = False) -> sqlite3.Connection:
    """Open an existing campaign; a missing, foreign or newer database is a one-line InputError.
    ``read_only`` (the verbs that only read): a database the user may not write is opened
    read-only instead of refused. A verb that records is refused at once when the user may not
    write the database, its folder or its journal files. The file is recognised as a campaign
    (its schema version) through a read-only connection first: a file refused, or only read, is
    left byte for byte as it was, with no journal files beside it."""
    folder = Path(folder)
    path = db_path(folder)
    _refuse_unusable(folder, path)
    blocked = _not_writable(path)
    if blocked is not None and not read_only:
        raise _read_only(blocked)
    con = None
    try:
        try:
            if blocked is not None:  # read as it is: a read-only connection, nothing made beside it
                con = _connect_read_only(path)
                _check_version(path, _version_row(con))
                return con
            try:  # recognised before anything may write to it (SQLite rolls a journal back, checkpoints a log)
                first = _connect_read_only(path, fallback=False)
            except sqlite3.OperationalError as exc:
                if _busy(exc):
                    raise
                first = None  # a rollback journal to roll back first: the read-write connection does
            if first is not None:
                try:
                    _check_version(path, _version_row(first))
                finally:
                    first.close()
            try:  # read-write: SQLite removes the log and its index it made when it closes
                con = _connect(path)
                row = _version_row(con)
            except sqlite3.OperationalError as exc:
                if con is not None:
                    con.close()
                    con = None
                locked_out = not _busy(exc) and ("readonly" in str(exc) or "unable to open" in str(exc))
                if locked_out and not read_only:
                    raise _read_only(path) from None
                if not locked_out:
                    raise
                con = _connect_read_only(path)
                row = _version_row(con)
            _check_version(path, row)
        except sqlite3.OperationalError as exc:
            if _busy(exc):  # another process holds it past the busy timeout
                raise InputError(f"{path}: busy: locked by another process (waited {LOCK_TIMEOUT_S:g} s); "
                                 "try again when it has finished") from None
            raise
    except sqlite3.DatabaseError as exc:
        if con is not None:
            con.close()
        full = "disk I/O error" in str(exc) and _disk_full(path)  # SQLite needs room for its index even to read
        raise InputError(f"{path}: cannot be read as a bmctl campaign database ({exc})"
                         + ("; the disk is full: SQLite needs room beside the database even to read it (free some "
                            "and try again; the database itself is not damaged by this)" if full else "")) from None
    except BaseException:
        if con is not None:
            con.close()
        raise
    return con


def _known_version(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and v in READ_VERSIONS


def version(con: sqlite3.Connection) -> int:
    """The campaign's schema version (one of :data:`READ_VERSIONS`, as :func:`open_db` checked)."""
    return int(con.execute("SELECT version FROM schema_version").fetchone()[0])


def upgrade(con: sqlite3.Connection) -> bool:
    """Bring a version-1 campaign to :data:`SCHEMA_VERSION` inside the caller's write transaction
    (a command refused later rolls it back with everything else): add ``sample_inputs``. The
    samples stored before it have no input hashes; ``sample`` matches them by their particles.
    Returns whether it upgraded."""
    if version(con) >= SCHEMA_VERSION:
        return False
    for stmt in SCHEMA_V2.strip().split(";"):
        if stmt.strip():
            con.execute(stmt)
    con.execute("UPDATE schema_version SET version = ?", (SCHEMA_VERSION,))
    return True


@contextlib.contextmanager
def transaction(con: sqlite3.Connection, write: bool = True, where: str = "campaign"):
    """One verb's transaction: ``BEGIN IMMEDIATE`` (write) or ``BEGIN`` (read); commit on success,
    roll back on any exception. A campaign locked by another command past the busy timeout is
    an InputError."""
    try:
        con.execute("BEGIN IMMEDIATE" if write else "BEGIN")
    except sqlite3.OperationalError as exc:
        if "locked" in str(exc) or "busy" in str(exc):
            raise InputError(f"{where}: busy: another bmctl campaign command is writing to it "
                             f"(waited {LOCK_TIMEOUT_S:g} s); try again when it has finished") from None
        raise
    try:
        yield con
    except BaseException:
        con.execute("ROLLBACK")
        raise
    else:
        con.execute("COMMIT")
        if write:
            _wal(con)


def _wal(con: sqlite3.Connection) -> None:
    """Put the campaign in WAL mode (readers are not blocked by a writer) after a verb's commit:
    a campaign is switched by the verbs that record to it, once they have, never by one that only
    reads or is refused. Where it cannot be switched now (a reader of a rollback-journal campaign
    holds it), the next verb that records switches it."""
    with contextlib.suppress(sqlite3.OperationalError):
        if str(con.execute("PRAGMA journal_mode").fetchone()[0]).lower() != "wal":
            con.execute("PRAGMA busy_timeout=0")  # not now: the verb has recorded what it did
            try:
                con.execute("PRAGMA journal_mode=WAL")
            finally:
                con.execute(f"PRAGMA busy_timeout={int(LOCK_TIMEOUT_S * 1000)}")


def init_schema(con: sqlite3.Connection) -> None:
    """Create the tables (inside the caller's transaction)."""
    for stmt in SCHEMA.strip().split(";"):
        if stmt.strip():
            con.execute(stmt)
    con.execute("INSERT INTO schema_version VALUES (?)", (SCHEMA_VERSION,))


# --- meta ---------------------------------------------------------------------------------------
def set_meta(con: sqlite3.Connection, **items) -> None:
    """Write meta keys (JSON values)."""
    for k, v in items.items():
        con.execute("INSERT OR REPLACE INTO meta VALUES (?, ?)", (k, json.dumps(v)))


def get_meta(con: sqlite3.Connection, where: str = "meta") -> dict:
    """All meta keys as a dict (a value that is not JSON is an InputError naming its key)."""
    out = {}
    for k, v in con.execute("SELECT key, value FROM meta"):
        if not isinstance(v, str):
            raise InputError(f"{where}: meta {str(k)[:40]!r}: not a JSON value (damaged or edited)")
        out[k] = bio.loads_json(v, f"{where}: meta {str(k)[:40]!r}")
    return out


# --- what a damaged or edited database may hold -------------------------------------------------
#: the largest float below 1: r is in [0, 1), as the particle-table reader takes it
BELOW_ONE = math.nextafter(1.0, 0.0)
#: numeric columns and the range every row must keep (NULL allowed where the schema allows it)
NUMERIC = (
    ("actions", "t0_h", 0.0, 1000.0, False), ("actions", "t1_h", 0.0, 1000.0, False),
    ("actions", "hours", 1e-12, 1000.0, False), ("actions", "rpm", 0.0, 1e5, False),
    ("actions", "milling", 0.0, 1.0, False), ("actions", "plan_id", 1, 2**62, True),
    ("temperatures", "t_h", 0.0, 1000.0, False), ("temperatures", "temperature_c", -50.0, 400.0, False),
    ("samples", "t_h", 0.0, 1000.0, False), ("samples", "n", 0, 2**62, False),
    ("samples", "um_per_px", 1e-300, 1e300, True), ("samples", "s_median_um", 1e-3, 1e4, False),
    ("samples", "r_median", 0.0, 1.0, False),
    ("particles", "sample_id", 1, 2**62, False), ("particles", "particle_id", 1, 2**62, False),
    ("particles", "x_um", -1e300, 1e300, True), ("particles", "y_um", -1e300, 1e300, True),
    ("particles", "area_um2", 0.0, 1e300, False), ("particles", "perimeter_um", 0.0, 1e300, False),
    ("particles", "s_um", 1e-3, 1e4, False), ("particles", "r", 0.0, BELOW_ONE, False),
    ("estimator_states", "t_h", -1.0, 1000.0, False),
    ("plans", "t_h", 0.0, 1000.0, False), ("plans", "rpm", 0.0, 1e5, False), ("plans", "milling", 0.0, 1.0, False),
    ("plans", "interval_h", 1e-12, 1000.0, False), ("plans", "advise_ms", 0.0, 1e12, False),
    ("decisions", "plan_id", 1, 2**62, False), ("decisions", "accepted", 0, 1, False),
    ("decisions", "rpm", 0.0, 1e5, True), ("decisions", "milling", 0.0, 1.0, True),
    ("sample_inputs", "sample_id", 1, 2**62, False), ("sample_inputs", "position", 1, 2**62, False),
)
#: columns of plain-data state BLOBs
BLOBS = (("estimator_states", "state"), ("plans", "controller_state"))
TEXT = (("actions", "deviation"), ("decisions", "note"), ("particles", "image"), ("sample_inputs", "source"),
        ("sample_inputs", "sha256"))


#: what every stored estimate holds (``init`` writes the prior with all of them): a finite
#: number in the range, and the same for its 90 % band ``_q05``/``_q95``
ESTIMATE_RANGES = {"s_mean_um": (1e-3, 1e4), "s_std_um": (0.0, 1e4), "r_mean": (0.0, 1.0), "r_std": (0.0, 1.0),
                   "temperature_c": (-273.15, 4000.0), "d50_um": (1e-3, 1e5)}
#: what else an estimate holds is a number too (the filter writes numbers only); these are read
#: by the verbs and the report and must be there
ESTIMATE_NUMBERS = ("t_h", "gamma_mult", "delta_mult")


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _check_estimate(doc, where: str) -> None:
    """An estimate document as the filter writes it: a table of finite numbers, with every key
    of :data:`ESTIMATE_RANGES` and its band in range and :data:`ESTIMATE_NUMBERS` there."""
    if not isinstance(doc, dict):
        raise InputError(f"{where}: not an estimate table")
    for k, v in doc.items():
        if not _number(v):
            raise InputError(f"{where}: {k[:60]!r} = {str(v)[:40]!r}: expected a number")
        if not math.isfinite(v):
            raise InputError(f"{where}: {k[:60]!r} = {v}: not finite")
    for k in ESTIMATE_NUMBERS:
        if k not in doc:
            raise InputError(f"{where}: {k}: missing")
    for k, (lo, hi) in ESTIMATE_RANGES.items():
        for key in (k, f"{k}_q05", f"{k}_q95"):
            v = doc.get(key)
            if not _number(v) or not lo <= v <= hi:
                raise InputError(f"{where}: {key}: " + ("missing" if key not in doc else f"{str(v)[:40]} is not a "
                                                        f"number in [{lo:g}, {hi:g}]"))


class _Doc(BaseModel):
    model_config = ConfigDict(extra="allow", strict=True)


class _Next(_Doc):
    rpm: Range(0.0, 1e5)
    milling: Range(0.0, 1.0)
    interval_h: Range(0.0, 1000.0)  # 0 at the batch end: the advice is the end state, nothing to run
    mill_min: Range(0.0, 60_000.0)
    rest_min: Range(0.0, 60_000.0)


class _Band(_Doc):
    median: Range(-1e300, 1e300)
    q05: Range(-1e300, 1e300)
    q95: Range(-1e300, 1e300)


class _Row(_Doc):
    """One interval of the plan advised to the batch end."""

    t0_h: Range(0.0, 1000.0)
    t1_h: Range(0.0, 1000.0)
    rpm: Range(0.0, 1e5)
    mill_min: Range(0.0, 60_000.0)
    rest_min: Range(0.0, 60_000.0)
    planned: StrictBool = True


_Text = Annotated[str, StringConstraints(max_length=2000)]


class AdviceDoc(_Doc):
    """What :func:`check` requires of a stored advice (``plans.advice``); other keys are kept."""

    t_h: Range(0.0, 1000.0)
    next: _Next
    estimate: dict
    target: dict[Annotated[str, StringConstraints(max_length=60)], Range(-1e300, 1e300)]
    reachable: dict[Annotated[str, StringConstraints(max_length=60)], StrictBool]
    binding: list[_Text]
    end: dict[str, _Band] = {}
    schedule: list[_Row] = []
    warnings: list[_Text] = []
    notes: list[_Text] = []
    sample_first: _Text | None = None
    solver: _Text = ""


def _check_advice(doc, where: str) -> None:
    """An advice document as ``advise`` writes it: the next action (finite rpm, milling share,
    interval and minutes), reachability per target key, binding limits as text, end bands."""
    from pydantic import ValidationError

    from ..config import format_validation_error
    from .targets import known_keys

    try:
        a = AdviceDoc.model_validate(doc)
    except ValidationError as exc:
        raise InputError(format_validation_error(where, exc)) from None
    for k in a.reachable:
        if k not in known_keys():
            raise InputError(f"{where}: reachable: {k[:60]!r} is not a target key")
    _check_estimate(doc["estimate"], f"{where}: estimate")


def _check_sources(doc, where: str) -> None:
    if not isinstance(doc, list) or not all(isinstance(x, str) and len(x) <= 4096 for x in doc):
        raise InputError(f"{where}: not a list of file names")


def _check_report(doc, where: str) -> None:
    if not isinstance(doc, list) or not all(isinstance(x, dict) for x in doc):
        raise InputError(f"{where}: not a list of tables")


#: columns of JSON text and the check of their documents
JSON_CHECKS = {("estimator_states", "estimate"): _check_estimate, ("plans", "advice"): _check_advice,
               ("samples", "sources"): _check_sources, ("samples", "report"): _check_report}


def check(con: sqlite3.Connection, path, prior: bool = True) -> None:
    """Refuse a damaged or edited database with one line naming the table, row and column.

    Every table of the schema must be there; every numeric column a number (not text or a
    BLOB) within its range (:data:`NUMERIC`); every JSON column a document of bounded depth
    (:func:`bmctl.io.loads_json`) with the content its verb writes (:data:`JSON_CHECKS`:
    estimates with every moment and band finite and in range, advice with a finite next
    action, the plan's rows, target and notes); state columns BLOBs; the rows' links (the
    filter's prior there unless ``prior`` is False, as while ``init`` writes it; every sample
    with particles). The states themselves are checked when they are read (:func:`unpack`).
    """
    try:
        have = {r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        old = version(con) < 2
        for stmt in SCHEMA.split(";"):
            words = stmt.split()
            if words[:2] == ["CREATE", "TABLE"] and words[2] not in have and not (old and words[2] in V2_TABLES):
                raise InputError(f"{path}: table {words[2]} missing (damaged, or not a bmctl campaign database)")
        for table, col, lo, hi, nullable in NUMERIC:
            if table not in have:  # a version-1 campaign's missing sample_inputs
                continue
            null = f"{col} IS NOT NULL AND " if nullable else ""
            row = con.execute(f"SELECT rowid, {col} FROM {table} WHERE {null}(typeof({col}) NOT IN ('real', 'integer') "
                              f"OR NOT ({col} BETWEEN ? AND ?)) LIMIT 1", (lo, hi)).fetchone()
            if row is not None:
                rng = f"[{lo:g}, 1)" if hi == BELOW_ONE else f"[{lo:g}, {hi:g}]"
                raise InputError(f"{path}: {table} row {row[0]}: {col} = {str(row[1])[:40]!r}: not a number in "
                                 f"{rng} (damaged or edited)")
        for table, col in BLOBS:
            row = con.execute(f"SELECT rowid FROM {table} WHERE typeof({col}) != 'blob' LIMIT 1").fetchone()
            if row is not None:
                raise InputError(f"{path}: {table} row {row[0]}: {col}: not a stored state (damaged or edited)")
        for table, col in TEXT:
            if table not in have:
                continue
            row = con.execute(f"SELECT rowid FROM {table} WHERE typeof({col}) != 'text' OR length({col}) > 100000 "
                              "LIMIT 1").fetchone()
            if row is not None:
                raise InputError(f"{path}: {table} row {row[0]}: {col}: not text of at most 100,000 characters "
                                 "(damaged or edited)")
        for (table, col), check_doc in JSON_CHECKS.items():
            for rowid, text in con.execute(f"SELECT rowid, {col} FROM {table}"):
                where = f"{path}: {table} row {rowid}: {col}"
                if not isinstance(text, str):
                    raise InputError(f"{where}: not a JSON document (damaged or edited)")
                check_doc(bio.loads_json(text, where), where)
        _check_links(con, path, prior, "sample_inputs" in have)
    except sqlite3.DatabaseError as exc:
        raise InputError(f"{path}: damaged campaign database ({exc})") from None


def _check_links(con: sqlite3.Connection, path, prior: bool = True, inputs: bool = True) -> None:
    """What the rows say of each other: the filter's prior is there (``prior``: ``init`` writes
    it, every estimate starts from it), every sample has particles and every particle a sample, and
    every input hash (``inputs``: a campaign with ``sample_inputs``) a sample."""
    if prior and con.execute("SELECT COUNT(*) FROM estimator_states WHERE t_h < 0").fetchone()[0] == 0:
        raise InputError(f"{path}: estimator_states: the prior (written by `campaign init`) is missing "
                         "(damaged or edited)")
    row = con.execute("SELECT id FROM samples WHERE id NOT IN (SELECT sample_id FROM particles) LIMIT 1").fetchone()
    if row is not None:
        raise InputError(f"{path}: samples row {row[0]}: no particles (damaged or edited)")
    row = con.execute("SELECT rowid, sample_id FROM particles WHERE sample_id NOT IN (SELECT id FROM samples) "
                      "LIMIT 1").fetchone()
    if row is not None:
        raise InputError(f"{path}: particles row {row[0]}: sample_id {row[1]} is no sample (damaged or edited)")
    if inputs:
        row = con.execute("SELECT rowid, sample_id FROM sample_inputs WHERE sample_id NOT IN (SELECT id FROM samples) "
                          "LIMIT 1").fetchone()
        if row is not None:
            raise InputError(f"{path}: sample_inputs row {row[0]}: sample_id {row[1]} is no sample (damaged or edited)")
    _check_timeline(con, path)


#: hours within which two batch times are one (``bmctl.campaign.workflow.EPS_H``: the log's own tolerance)
TIME_TOL_H = 1e-9


def _check_timeline(con: sqlite3.Connection, path) -> None:
    """What ``log`` and ``sample`` keep across rows: each logged interval starts where the one before
    it ended or later (never inside it), its ``hours`` are its ``t1_h - t0_h``, no estimator node is
    after the logged clock (the end of the last interval; 0 before any), and each sample's ``n``
    is the number of its stored particles."""
    row = con.execute("SELECT id, t0_h, prev FROM (SELECT id, t0_h, LAG(t1_h) OVER (ORDER BY t0_h, id) AS prev "
                      "FROM actions) WHERE t0_h < prev - ? LIMIT 1", (TIME_TOL_H,)).fetchone()
    if row is not None:
        raise InputError(f"{path}: actions row {row[0]}: t0_h = {row[1]:.12g} is inside the interval before it "
                         f"(which ends at {row[2]:.12g} h): the log is append-only (damaged or edited)")
    row = con.execute("SELECT id, hours, t1_h - t0_h FROM actions WHERE abs(hours - (t1_h - t0_h)) > ? LIMIT 1",
                      (TIME_TOL_H,)).fetchone()
    if row is not None:
        raise InputError(f"{path}: actions row {row[0]}: hours = {row[1]:.12g}, not t1_h - t0_h = {row[2]:.12g} "
                         "(damaged or edited)")
    row = con.execute("SELECT id, t_h, clock FROM estimator_states, (SELECT COALESCE(MAX(t1_h), 0.0) AS clock "
                      "FROM actions) WHERE t_h > clock + ? ORDER BY t_h LIMIT 1", (TIME_TOL_H,)).fetchone()
    if row is not None:
        raise InputError(f"{path}: estimator_states row {row[0]}: t_h = {row[1]:.12g} is after the logged clock "
                         f"({row[2]:.12g} h; the estimate reaches no further than the log) (damaged or edited)")
    row = con.execute("SELECT s.id, s.n, COUNT(p.sample_id) FROM samples AS s LEFT JOIN particles AS p "
                      "ON p.sample_id = s.id GROUP BY s.id HAVING s.n != COUNT(p.sample_id) LIMIT 1").fetchone()
    if row is not None:
        raise InputError(f"{path}: samples row {row[0]}: n = {row[1]}, but {row[2]} particles are stored for it "
                         "(damaged or edited)")


def check_inputs(folder: str | Path, inputs: dict, where: str) -> None:
    """Every input copied at ``init`` (``meta.inputs``): a file under ``DIR/inputs/`` (no other
    path), a regular file, with the checksum recorded then. A crafted path or an edited copy is
    refused by every verb, before anything is read from it."""
    folder = Path(folder)
    for key, m in inputs.items():
        name = f"{where}: meta 'inputs': {key[:40]!r}"
        rel = Path(m["file"])
        if rel.parts[:1] != (INPUTS,) or len(rel.parts) < 2:
            raise InputError(f"{name}: {m['file'][:80]!r} is not a file under {INPUTS}/ (damaged or edited)")
        p = bio.inside(folder / INPUTS, str(Path(*rel.parts[1:])), name)
        try:
            digest = hashlib.sha256(bio.read_input_bytes(p)).hexdigest()
        except InputError:
            digest = None
        if digest != m["sha256"]:
            raise InputError(f"{p}: changed or missing since `campaign init` (the campaign runs on the copy taken "
                             f"then; sha256 {str(m['sha256'])[:12]}...)")


# --- plain-data states as BLOBs -----------------------------------------------------------------
def pack(state: dict) -> bytes:
    """A plain-data state (nested dicts, lists, numbers, strings, arrays) as ``.npz`` bytes."""
    arrays: dict[str, np.ndarray] = {}
    doc = _split(state, "", arrays)
    buf = io.BytesIO()
    np.savez(buf, **{JSON_KEY: np.array(json.dumps(doc, allow_nan=True))}, **arrays)
    return buf.getvalue()


def unpack(blob: bytes, where: str = "state") -> dict:
    """Inverse of :func:`pack` (plain data only, bounded: :func:`bmctl.io.load_npz`,
    :func:`bmctl.io.loads_json`); damaged bytes are an InputError."""
    if not isinstance(blob, (bytes, bytearray)):
        raise InputError(f"{where}: damaged state (not a stored state)")
    arrays = bio.load_npz(bytes(blob), f"{where}: damaged state")
    if JSON_KEY not in arrays or arrays[JSON_KEY].dtype.kind != "U" or arrays[JSON_KEY].ndim != 0:
        raise InputError(f"{where}: damaged state (no JSON part)")
    doc = bio.loads_json(str(arrays.pop(JSON_KEY)), f"{where}: damaged state")
    try:
        return _join(doc, arrays)
    except (KeyError, TypeError):
        raise InputError(f"{where}: damaged state (an array reference without its array)") from None


__all__ = ["ARRAY_TAG", "DB_NAME", "SCHEMA_VERSION", "READ_VERSIONS", "LOCK_TIMEOUT_S", "create", "open_db",
           "refuse_read_only", "transaction", "version", "upgrade", "init_schema", "set_meta", "get_meta", "check",
           "check_inputs", "pack", "unpack", "now", "db_path"]
