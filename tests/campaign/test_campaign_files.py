"""The campaign's files: the database's mode under the umask, an init that does not finish, an
empty database file, a database another process holds locked."""

from __future__ import annotations

import os
import sqlite3
import stat

import pytest

from bmctl import campaign as cp
from bmctl.campaign import db, workflow
from bmctl.errors import InputError

from .test_campaign import _init


@pytest.mark.parametrize("umask, mode", [(0o002, 0o664), (0o027, 0o640)])
def test_the_database_takes_the_users_umask(tmp_path, umask, mode):
    """SQLite makes a new database 0644 whatever the umask: a group that shares a campaign under
    umask 002 could not record to it."""
    old = os.umask(umask)
    try:
        _init(tmp_path / "c")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "c" / db.DB_NAME).stat().st_mode) == mode
    assert stat.S_IMODE((tmp_path / "c" / db.INPUTS).stat().st_mode) == 0o777 & ~umask


def test_an_init_that_does_not_finish_leaves_no_campaign(tmp_path, monkeypatch):
    """Ctrl-C while the prior is written left a database without it: every verb then called it
    damaged and init refused the folder."""
    def interrupted(self, t_h):
        raise KeyboardInterrupt

    monkeypatch.setattr(workflow.Campaign, "_write_node", interrupted)
    with pytest.raises(KeyboardInterrupt):
        _init(tmp_path / "c")
    assert not (tmp_path / "c").exists()
    monkeypatch.undo()
    _init(tmp_path / "c")
    assert cp.status(tmp_path / "c")["clock_h"] == 0.0


def test_an_empty_database_file_is_refused_untouched(tmp_path):
    d = tmp_path / "c"
    d.mkdir()
    (d / db.DB_NAME).write_bytes(b"")
    with pytest.raises(InputError, match="empty"):
        cp.status(d)
    assert (d / db.DB_NAME).stat().st_size == 0


def test_a_database_another_process_holds_is_busy_not_damaged(tmp_path, monkeypatch):
    d = tmp_path / "c"
    _init(d)
    monkeypatch.setattr(db, "LOCK_TIMEOUT_S", 0.2)
    holder = sqlite3.connect(str(d / db.DB_NAME), isolation_level=None)
    holder.execute("PRAGMA locking_mode=EXCLUSIVE")
    holder.execute("BEGIN EXCLUSIVE")
    holder.execute("SELECT COUNT(*) FROM meta").fetchone()
    try:
        for verb in (lambda: cp.status(d), lambda: cp.log(d, 300, 0.5)):
            with pytest.raises(InputError, match="busy: locked by another process"):
                verb()
    finally:
        holder.execute("ROLLBACK")
        holder.close()
    cp.log(d, 300, 0.5)


def test_a_read_only_campaign_with_a_write_ahead_log_is_refused_not_read_stale(tmp_path, monkeypatch):
    """A campaign folder the user may not write, with commits still in campaign.sqlite-wal (copied or
    archived while a command had it open): SQLite cannot open the log read-only there, and the
    ``immutable`` fallback read the database file without them (a reading missing, silently)."""
    d = tmp_path / "c"
    _init(d)
    writer = sqlite3.connect(str(d / db.DB_NAME), isolation_level=None)
    writer.execute("PRAGMA wal_autocheckpoint=0")
    writer.execute("INSERT INTO temperatures (t_h, temperature_c, action_id, logged_at) VALUES (0, 30, NULL, 'x')")
    assert (d / (db.DB_NAME + "-wal")).stat().st_size > 0
    real_connect = sqlite3.connect

    def read_only_folder(target, *args, **kwargs):  # what SQLite does where it cannot make the -shm file
        if "mode=ro" in str(target) and "immutable" not in str(target):
            raise sqlite3.OperationalError("unable to open database file")
        return real_connect(target, *args, **kwargs)

    def locked(path):
        raise sqlite3.OperationalError("attempt to write a readonly database")

    monkeypatch.setattr(db, "_connect", locked)
    monkeypatch.setattr(sqlite3, "connect", read_only_folder)
    try:
        with pytest.raises(InputError, match="write-ahead log"):
            cp.status(d)
    finally:
        writer.close()
