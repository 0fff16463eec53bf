"""Opening and making campaign.sqlite: an init that fails early leaves nothing; a file is recognised
as a campaign before anything writes to it (a refused or read-only verb leaves it byte for byte as
it was, with no journal files beside it); a campaign the user may not write is refused by the verbs
that record before any work; what is in the way is named as what it is."""

from __future__ import annotations

import os
import shutil
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

from bmctl import campaign as cp
from bmctl.campaign import db
from bmctl.cli import main
from bmctl.errors import InputError

from .test_campaign import CARD, RECIPE, ROOT, _init

SIDECARS = ("-wal", "-shm", "-journal")
VERBS = {  # each verb's arguments after DIR; status and report only read
    "status": [], "report": [], "log": ["--rpm", "300", "--hours", "0.5"], "decide": ["--accept"], "advise": [],
    "sample": ["--at-h", "0.5", str(ROOT / "examples" / "samples" / "lab-300rpm-0p5h.csv")],
}
WRITE_VERBS = ("log", "decide", "advise", "sample")


@pytest.fixture(scope="module")
def advised(tmp_path_factory):
    """A campaign with a logged interval and an advice for the logged time (decide can record)."""
    d = tmp_path_factory.mktemp("advised") / "c"
    _init(d)
    cp.log(d, 300.0, 0.5)
    cp.advise(d)
    return d


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def _init_argv(d) -> list[str]:
    return ["campaign", "init", str(d), "--model", str(CARD), "--controller", str(RECIPE), "--target", "d50_um=45",
            "--hours", "2", "--particles", "60"]


def _err_line(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err.strip()


def _files(d: Path) -> dict[str, bytes | None]:
    """What the folder holds: each file's bytes (None for a folder)."""
    return {p.name: (p.read_bytes() if p.is_file() else None) for p in sorted(d.iterdir())}


def _header_modes(path: Path) -> bytes:
    """The file format's write and read versions (bytes 18-19): 01 01 rollback journal, 02 02 WAL."""
    return path.read_bytes()[18:20]


def _journal_mode(path: Path, mode: str) -> None:
    con = sqlite3.connect(str(path))
    con.execute(f"PRAGMA journal_mode={mode}")
    con.close()


# --- bug 1: an init that fails or is interrupted early -----------------------------------------------
@pytest.mark.parametrize("side", SIDECARS)
def test_init_names_a_folder_where_sqlite_keeps_its_journal_and_leaves_nothing(tmp_path, capsys, side):
    """It said "campaign.sqlite: damaged campaign database (unable to open database file)" and left a
    0-byte campaign.sqlite, after which the folder "already holds a campaign"."""
    d = tmp_path / "X"
    (d / (db.DB_NAME + side)).mkdir(parents=True)
    assert main(_init_argv(d)) == 2
    line = _err_line(capsys)
    assert f"{d / (db.DB_NAME + side)}: is in the way (a folder)" in line and "damaged" not in line, line
    assert sorted(p.name for p in d.iterdir()) == [db.DB_NAME + side]
    (d / (db.DB_NAME + side)).rmdir()
    assert main(_init_argv(d)) == 0


def test_init_refuses_a_stray_log_file_rather_than_reading_it_as_the_new_campaigns(tmp_path, capsys):
    """A -wal file left by another database would be replayed into the new one."""
    d = tmp_path / "X"
    d.mkdir()
    (d / (db.DB_NAME + "-wal")).write_bytes(b"not ours")
    assert main(_init_argv(d)) == 2
    assert "campaign.sqlite-wal: is in the way (a file)" in _err_line(capsys)
    assert _files(d) == {db.DB_NAME + "-wal": b"not ours"}


@pytest.mark.parametrize("interrupt", [KeyboardInterrupt(), sqlite3.OperationalError("disk I/O error")])
def test_an_init_interrupted_while_the_database_is_made_leaves_nothing(tmp_path, monkeypatch, interrupt):
    """Ctrl-C (or an SQLite error) inside db.create, before init's undo covered it, left a half-made
    campaign.sqlite: every verb then refused the folder, init too ("already holds a campaign")."""
    def connect(path):
        raise interrupt

    monkeypatch.setattr(db, "_connect", connect)
    with pytest.raises(type(interrupt)):
        _init(tmp_path / "c")
    assert not (tmp_path / "c").exists()
    (tmp_path / "d").mkdir()
    with pytest.raises(type(interrupt)):
        _init(tmp_path / "d")
    assert list((tmp_path / "d").iterdir()) == []
    monkeypatch.undo()
    _init(tmp_path / "c")
    assert cp.status(tmp_path / "c")["clock_h"] == 0.0


def test_an_init_sqlite_cannot_write_is_not_called_damaged(tmp_path, capsys, monkeypatch):
    def broken(con):
        raise sqlite3.OperationalError("disk I/O error")

    monkeypatch.setattr(db, "init_schema", broken)
    assert main(_init_argv(tmp_path / "c")) == 2
    line = _err_line(capsys)
    assert "campaign.sqlite: cannot be written as a campaign database (disk I/O error)" in line, line
    assert not (tmp_path / "c").exists()


def test_init_into_a_file_says_it_is_a_file(tmp_path, capsys):
    """It said "afile: File exists"."""
    f = tmp_path / "afile"
    f.write_text("mine\n", encoding="utf-8")
    assert main(_init_argv(f)) == 2
    assert f"{f}: is a file, not a folder" in _err_line(capsys)
    assert f.read_text(encoding="utf-8") == "mine\n"


def test_init_over_a_campaign_leaves_it_as_it_was(advised, tmp_path, capsys):
    d = _copy(advised, tmp_path / "c")
    before = _files(d)
    assert main(_init_argv(d)) == 2
    assert "already holds a campaign" in _err_line(capsys)
    assert _files(d) == before


# --- bug 2: nothing is written before the file is recognised; reading writes nothing -------------------
@pytest.mark.parametrize("verb", list(VERBS))
@pytest.mark.parametrize("wal", [False, True])
def test_another_applications_database_is_refused_byte_for_byte_unchanged(tmp_path, capsys, verb, wal):
    """Every verb switched another application's SQLite file to WAL (header 01 01 -> 02 02) while
    refusing it."""
    d = tmp_path / "fo"
    d.mkdir()
    con = sqlite3.connect(str(d / db.DB_NAME))
    if wal:
        con.execute("PRAGMA journal_mode=WAL")
    con.execute("CREATE TABLE a (x)")
    con.execute("INSERT INTO a VALUES (1)")
    con.commit()
    con.close()
    before = _files(d)
    assert main(["campaign", verb, str(d), *VERBS[verb]]) == 2
    line = _err_line(capsys)
    assert f"{d / db.DB_NAME}: cannot be read as a bmctl campaign database (no such table: schema_version)" in line
    assert _files(d) == before  # the header too (bytes 18-19), and no -wal, -shm or -journal left


@pytest.mark.parametrize("verb", ["status", "report"])
def test_the_verbs_that_read_leave_a_rollback_journal_campaign_as_it_is(advised, tmp_path, capsys, verb):
    """`status` switched a campaign set to journal_mode=DELETE to WAL."""
    d = _copy(advised, tmp_path / "c")
    _journal_mode(d / db.DB_NAME, "DELETE")
    before = _files(d)
    assert _header_modes(d / db.DB_NAME) == b"\x01\x01"
    assert main(["campaign", verb, str(d), *(["--out", str(tmp_path / "r.html")] if verb == "report" else [])]) == 0
    assert _files(d) == before


@pytest.mark.parametrize("verb", ["status", "report"])
def test_the_verbs_that_read_leave_no_journal_files_beside_a_wal_campaign(advised, tmp_path, capsys, verb):
    d = _copy(advised, tmp_path / "c")
    assert _header_modes(d / db.DB_NAME) == b"\x02\x02"
    before = _files(d)
    assert main(["campaign", verb, str(d), *(["--out", str(tmp_path / "r.html")] if verb == "report" else [])]) == 0
    assert _files(d) == before


def test_a_verb_that_records_switches_a_rollback_journal_campaign_to_wal_once_it_has(advised, tmp_path, capsys):
    """A refused `log` leaves the file as it was (it was switched to WAL before the refusal); one
    that records puts the campaign back in WAL mode."""
    d = _copy(advised, tmp_path / "c")
    _journal_mode(d / db.DB_NAME, "DELETE")
    before = _files(d)
    assert main(["campaign", "log", str(d), "--rpm", "300", "--hours", "0.5", "--from-h", "2"]) == 2
    assert "leaves a gap" in _err_line(capsys)
    assert _files(d) == before
    assert main(["campaign", "log", str(d), "--rpm", "300", "--hours", "0.5"]) == 0
    assert _header_modes(d / db.DB_NAME) == b"\x02\x02"
    assert sorted(p.name for p in d.iterdir()) == sorted(before)
    assert cp.status(d)["counts"]["actions"] == 2


def test_an_init_makes_a_wal_campaign(tmp_path):
    _init(tmp_path / "c")
    assert _header_modes(tmp_path / "c" / db.DB_NAME) == b"\x02\x02"
    assert sorted(p.name for p in (tmp_path / "c").iterdir()) == [db.DB_NAME, db.INPUTS]


def test_a_rollback_journal_left_by_a_killed_writer_is_rolled_back_and_read(advised, tmp_path, capsys):
    """A rollback-journal campaign whose writer was killed mid-transaction: the file holds pages of the
    transaction that did not finish, the journal the pages to put back."""
    d = _copy(advised, tmp_path / "c")
    _journal_mode(d / db.DB_NAME, "DELETE")
    code = ("import os, sqlite3, sys\n"
            "con = sqlite3.connect(sys.argv[1], isolation_level=None)\n"
            "con.execute('PRAGMA cache_size=1')\n"
            "con.execute('BEGIN')\n"
            "con.execute(\"UPDATE particles SET s_um = 5000\")\n"
            "con.execute(\"INSERT INTO meta WITH RECURSIVE r(i) AS (SELECT 1 UNION ALL SELECT i + 1 FROM r "
            "WHERE i < 200) SELECT 'k' || i, hex(randomblob(4000)) FROM r\")\n"
            "os._exit(0)\n")
    subprocess.run([sys.executable, "-c", code, str(d / db.DB_NAME)], check=True)
    assert (d / (db.DB_NAME + "-journal")).stat().st_size > 0
    assert main(["campaign", "status", str(d)]) == 0
    assert not (d / (db.DB_NAME + "-journal")).exists()
    assert cp.status(d)["counts"]["actions"] == 1


# --- bug 3: a campaign the user may not write ---------------------------------------------------------
def _deny_writes(monkeypatch, *paths: Path) -> None:
    """os.access says this user may not write ``paths`` (the tests run as root, who may write anything)."""
    real = os.access
    denied = {os.path.realpath(p) for p in paths}

    def access(p, mode, *args, **kwargs):
        if mode & os.W_OK and os.path.realpath(p) in denied:
            return False
        return real(p, mode, *args, **kwargs)

    monkeypatch.setattr(os, "access", access)


@pytest.mark.parametrize("verb", WRITE_VERBS)
@pytest.mark.parametrize("what", ["database", "folder", "-shm"])
def test_a_verb_that_records_is_refused_before_any_work_where_the_user_may_not_write(advised, tmp_path, capsys,
                                                                                      monkeypatch, verb, what):
    """It said "damaged campaign database (attempt to write a readonly database)" (advise: after planning)."""
    d = _copy(advised, tmp_path / "c")
    if what == "-shm":  # left, read-only, by a reader of the campaign while it was read-only
        (d / (db.DB_NAME + "-shm")).write_bytes(b"")
    p = {"database": d / db.DB_NAME, "folder": d, "-shm": d / (db.DB_NAME + "-shm")}[what]
    _deny_writes(monkeypatch, p)
    work = []  # advise plans, sample measures its images: neither before the refusal
    from bmctl.campaign import mill, workflow

    monkeypatch.setattr(mill.CampaignLoop, "decide_at", lambda *a, **k: work.append("planned"))
    monkeypatch.setattr(workflow, "_measure", lambda *a, **k: work.append("measured"))
    before = _files(d)
    assert main(["campaign", verb, str(d), *VERBS[verb]]) == 2
    line = _err_line(capsys)
    assert line.startswith(f"bmctl: error: {p}: read-only for this user") and "damaged" not in line, line
    assert not work
    assert _files(d) == before


@pytest.mark.parametrize("verb", ["status", "report"])
def test_the_verbs_that_read_read_a_campaign_the_user_may_not_write_and_leave_nothing(advised, tmp_path, capsys,
                                                                                      monkeypatch, verb):
    d = _copy(advised, tmp_path / "c")
    _deny_writes(monkeypatch, d / db.DB_NAME)
    before = _files(d)
    assert main(["campaign", verb, str(d), *(["--out", str(tmp_path / "r.html")] if verb == "report" else [])]) == 0
    assert _files(d) == before


def _unprivileged() -> list[str]:
    """Run a command as this user without root's permission overrides (file modes then hold)."""
    if os.geteuid() != 0:
        return []
    setpriv = shutil.which("setpriv")
    if setpriv is None:
        pytest.skip("running as root without setpriv: file modes do not hold")
    return [setpriv, "--bounding-set=-dac_override,-dac_read_search,-fowner"]


def _bmctl(*argv) -> subprocess.CompletedProcess:
    return subprocess.run([*_unprivileged(), sys.executable, "-m", "bmctl", *map(str, argv)], capture_output=True,
                          text=True, timeout=300)


def test_a_read_only_database_file_in_a_writable_folder(advised, tmp_path):
    """chmod 444 campaign.sqlite: log and decide said "damaged campaign database (attempt to write a
    readonly database)", and `status` left read-only -wal and -shm files beside it that kept the
    campaign read-only once its write permission was back."""
    d = _copy(advised, tmp_path / "c")
    (d / db.DB_NAME).chmod(0o444)
    before = _files(d)
    for verb in ("log", "decide"):
        r = _bmctl("campaign", verb, d, *VERBS[verb])
        assert r.returncode == 2, r.stderr
        assert r.stderr.strip() == (f"bmctl: error: {d / db.DB_NAME}: read-only for this user: this command records "
                                    "to the campaign (`status` and `report` read it as it is)"), r.stderr
    r = _bmctl("campaign", "status", d)
    assert r.returncode == 0 and "logged to 0.5 of 2 h" in r.stdout, r.stderr
    assert _files(d) == before
    (d / db.DB_NAME).chmod(0o644)
    r = _bmctl("campaign", "decide", d, "--accept")
    assert r.returncode == 0, r.stderr


# --- bug 4: what is in the way, named as what it is ---------------------------------------------------
def test_a_text_schema_version_is_not_an_integer(advised, tmp_path, capsys):
    """It said "campaign schema version 2, this bmctl reads 1 and 2"."""
    d = _copy(advised, tmp_path / "c")
    con = sqlite3.connect(str(d / db.DB_NAME))
    con.execute("DROP TABLE schema_version")
    con.execute("CREATE TABLE schema_version (version)")
    con.execute("INSERT INTO schema_version VALUES ('2')")
    con.commit()
    con.close()
    before = _files(d)
    for verb in ("status", "log"):
        assert main(["campaign", verb, str(d), *VERBS[verb]]) == 2
        assert f"{d / db.DB_NAME}: schema_version '2': not an integer" in _err_line(capsys)
    assert _files(d) == before


@pytest.mark.parametrize("verb", list(VERBS))
def test_a_folder_named_campaign_sqlite_is_a_folder(tmp_path, capsys, verb):
    """`log` said "read-only for this user", `status` "disk I/O error"."""
    d = tmp_path / "c"
    (d / db.DB_NAME).mkdir(parents=True)
    assert main(["campaign", verb, str(d), *VERBS[verb]]) == 2
    assert _err_line(capsys) == f"bmctl: error: {d / db.DB_NAME}: is a folder, not a campaign database"
    assert sorted(p.name for p in d.iterdir()) == [db.DB_NAME]


@pytest.mark.parametrize("side", ["-wal", "-shm"])
@pytest.mark.parametrize("verb", ["status", "log"])
def test_a_folder_where_sqlite_keeps_the_log_is_in_the_way(advised, tmp_path, capsys, side, verb):
    d = _copy(advised, tmp_path / "c")
    (d / (db.DB_NAME + side)).mkdir()
    before = _files(d)
    assert main(["campaign", verb, str(d), *VERBS[verb]]) == 2
    assert f"{d / (db.DB_NAME + side)}: is in the way (a folder)" in _err_line(capsys)
    assert _files(d) == before


def test_a_symlink_loop_at_campaign_sqlite_is_named(tmp_path, capsys):
    """It said "no campaign here (campaign.sqlite not found)"."""
    d = tmp_path / "c"
    d.mkdir()
    (d / db.DB_NAME).symlink_to(db.DB_NAME)
    assert main(["campaign", "status", str(d)]) == 2
    assert f"{d / db.DB_NAME}: is a symlink loop (it cannot be resolved)" in _err_line(capsys)
    (d / db.DB_NAME).unlink()
    (d / db.DB_NAME).symlink_to("elsewhere.sqlite")
    assert main(["campaign", "log", str(d), "--rpm", "300", "--hours", "0.5"]) == 2
    assert f"{d / db.DB_NAME}: is a symlink to 'elsewhere.sqlite', which does not exist" in _err_line(capsys)
    assert not (d / "elsewhere.sqlite").exists()


def test_a_campaign_reached_through_a_symlink_is_read_and_written(advised, tmp_path, capsys):
    d = _copy(advised, tmp_path / "c")
    e = tmp_path / "e"
    e.mkdir()
    (e / db.DB_NAME).symlink_to(d / db.DB_NAME)
    (e / db.INPUTS).symlink_to(d / db.INPUTS)
    assert main(["campaign", "status", str(e)]) == 0
    assert main(["campaign", "decide", str(e), "--accept"]) == 0
    assert sorted(p.name for p in e.iterdir()) == [db.DB_NAME, db.INPUTS]


def test_a_missing_campaign_is_still_not_found(tmp_path):
    with pytest.raises(InputError, match="no campaign here"):
        cp.status(tmp_path)


# --- what the rows say of each other --------------------------------------------------------------------
@pytest.fixture(scope="module")
def sampled(tmp_path_factory):
    """Two logged intervals (0-0.5-1 h), a sample at 0.5 h and an advice."""
    d = tmp_path_factory.mktemp("sampled") / "c"
    _init(d)
    cp.log(d, 300.0, 0.5)
    cp.log(d, 0.0, 0.5)
    cp.sample(d, 0.5, [ROOT / "examples" / "samples" / "lab-300rpm-0p5h.csv"])
    cp.advise(d)
    return d


@pytest.mark.parametrize("damage, named", [
    ("UPDATE actions SET t0_h = 0.4, hours = 0.6 WHERE id = 2",
     "actions row 2: t0_h = 0.4 is inside the interval before it (which ends at 0.5 h)"),
    ("UPDATE actions SET t0_h = 0, hours = 1 WHERE id = 2", "actions row 2: t0_h = 0 is inside the interval before it"),
    ("UPDATE actions SET hours = 0.25 WHERE id = 2", "actions row 2: hours = 0.25, not t1_h - t0_h = 0.5"),
    ("UPDATE actions SET t1_h = 0.75 WHERE id = 2", "actions row 2: hours = 0.5, not t1_h - t0_h = 0.25"),
    ("DELETE FROM actions WHERE id = 2", "t_h = 1 is after the logged clock (0.5 h"),
    ("INSERT INTO estimator_states (t_h, state, estimate, created_at) SELECT 1.5, state, estimate, created_at "
     "FROM estimator_states WHERE t_h = 1", "t_h = 1.5 is after the logged clock (1 h"),
    ("UPDATE samples SET n = n + 1", "samples row 1: n = "),
    ("DELETE FROM particles WHERE particle_id = 1", "samples row 1: n = "),
])
@pytest.mark.parametrize("verb", ["status", "log"])
def test_rows_that_contradict_each_other_are_refused(sampled, tmp_path, capsys, damage, named, verb):
    """An interval inside the one before it, hours that are not its length, an estimate after the
    logged clock, a sample whose particle count is not its particles: each was read as it was."""
    d = _copy(sampled, tmp_path / "c")
    con = sqlite3.connect(str(d / db.DB_NAME))
    con.execute(damage)
    con.commit()
    con.close()
    before = _files(d)
    assert main(["campaign", verb, str(d), *VERBS[verb]]) == 2
    line = _err_line(capsys)
    assert f"{d / db.DB_NAME}: " in line and named in line and "(damaged or edited)" in line, line
    assert _files(d) == before


def test_the_rows_a_campaign_writes_agree(sampled, tmp_path):
    """A log started at the clock (--from-h), a sample taken before the clock and one after it: the
    checks of the rows hold for everything the verbs write (they refuse no campaign of their own)."""
    d = _copy(sampled, tmp_path / "c")
    cp.log(d, 300.0, 1 / 3, from_h=1.0)
    cp.sample(d, 1.9, [ROOT / "examples" / "samples" / "lab-300rpm-1h.csv"])  # after the clock: waits
    cp.log(d, 300.0, 0.1 + 0.2)
    cp.sample(d, 1.0, [ROOT / "examples" / "samples" / "lab-300rpm-2h.csv"])
    assert cp.status(d)["counts"]["samples"] == 3
    with cp.Campaign(d) as c:
        db.check(c.con, "x")
