"""The project store: one experiment = one SQLite file (`NAME.sandtrack`).

Every edit is committed at once (WAL journal, synchronous=FULL), so a killed process or a
dropped SSH link loses nothing; there is no save step. Long runs (tracking) commit their chunks
without waiting for the disk and sync once at the end (`Project.edit(sync_each_write=False)`).

Tables
- ``meta(key, value)``: ``schema_version``, creation time, and other facts about the file that are
  not edits (undo leaves them).
- ``videos(camera, path, fingerprint, width, height, fps, frames)``: one row per camera
  ("side", "front", or any name for more cameras).
- ``settings(key, value)``: JSON values: ``sync_offset_s`` (s; front started that much later),
  ``board`` (BoardSpec fields), ``calibration`` (calibration.toml text), ``model`` (path and
  metrics of the regression model), anything else a step needs to remember.
- ``markers(id, label)``.
- ``points(frame, camera, marker, x_px, y_px, status, score, psr, colour_frac)``: pixel position
  of a marker in one camera's own frame index; status is one of STATUSES.
- ``edits(id, kind, description, created, undone)`` and ``edit_rows(edit_id, seq, table_name,
  key, before, after)``: the edit log that undo/redo walks (undo applies an edit's rows' "before"
  in reverse order, redo their "after" in order). A row is one point, marker or setting, or (table
  ``points_batch``, from version 3) one write of many points: key, before and after are JSON lists,
  one entry per point, null where the point did not exist; its "after" is logged when it is undone.
"""

from __future__ import annotations

import json
import math
import os
import sqlite3
import time
from collections.abc import Iterable, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from .errors import SandtrackError

SCHEMA_VERSION = 3
LABEL_MAX = 16  # characters of a marker label
STATUSES = ("tracked", "occluded", "lost", "manual", "interpolated", "imported")
POINT_COLUMNS = ["frame", "camera", "marker", "x_px", "y_px", "status", "score", "psr", "colour_frac"]
_POINT_VALUES = POINT_COLUMNS[3:]
_PUT_POINT = f"INSERT OR REPLACE INTO points ({', '.join(POINT_COLUMNS)}) VALUES (?,?,?,?,?,?,?,?,?)"
_DELETE_POINT = "DELETE FROM points WHERE frame=? AND camera=? AND marker=?"

_SCHEMA_V1 = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS videos (
    camera TEXT PRIMARY KEY, path TEXT NOT NULL, fingerprint TEXT NOT NULL,
    width INTEGER, height INTEGER, fps REAL, frames INTEGER);
CREATE TABLE IF NOT EXISTS settings (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS markers (id INTEGER PRIMARY KEY, label TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS points (
    frame INTEGER NOT NULL, camera TEXT NOT NULL, marker INTEGER NOT NULL,
    x_px REAL, y_px REAL, status TEXT NOT NULL, score REAL, psr REAL, colour_frac REAL,
    PRIMARY KEY (marker, camera, frame)) WITHOUT ROWID;
CREATE INDEX IF NOT EXISTS points_by_frame ON points (frame, camera);
CREATE TABLE IF NOT EXISTS edits (
    id INTEGER PRIMARY KEY AUTOINCREMENT, kind TEXT NOT NULL, description TEXT NOT NULL,
    created REAL NOT NULL, undone INTEGER NOT NULL DEFAULT 0);
CREATE TABLE IF NOT EXISTS edit_rows (
    edit_id INTEGER NOT NULL, seq INTEGER NOT NULL, table_name TEXT NOT NULL,
    key TEXT NOT NULL, before TEXT, after TEXT, PRIMARY KEY (edit_id, seq));
"""

_V1_TO_V2 = """
CREATE INDEX IF NOT EXISTS edit_rows_by_key ON edit_rows (edit_id, key);
"""

# Version 3 logs a write of many points as one edit_rows row (table_name 'points_batch'): nothing to
# change in the file, but an older version could not undo such rows.
_V2_TO_V3 = ""

# Migrations from version N to N+1; index 0 creates version 1.
MIGRATIONS: list[str] = [_SCHEMA_V1, _V1_TO_V2, _V2_TO_V3]


# Connections this process holds per project file (see Project.open).
_open_count: dict[str, int] = {}


def _key(path: Path) -> str:
    try:
        return str(path.resolve())
    except OSError:
        return str(path)


# A damaged file shows as an SQLite error, or as text that is not UTF-8 where SQLite returns text.
_DAMAGE = (sqlite3.DatabaseError, UnicodeDecodeError)


def _open_error(path: Path, exc: Exception) -> SandtrackError:
    if "readonly" in str(exc) or "unable to open" in str(exc):
        return SandtrackError(f"{path}: cannot open the project: the file or its folder is read-only "
                              f"(SQLite needs to write beside it; use a writable copy)")
    return SandtrackError(f"{path}: project file is damaged ({str(exc).splitlines()[0][:200]})")


def _check_version(path: Path, version: int | None) -> None:
    if version is None:
        raise SandtrackError(f"{path}: not a sandtrack project (no schema version)")
    if version < 1:
        raise SandtrackError(f"{path}: project file is damaged (schema version {version})")
    if version > SCHEMA_VERSION:
        raise SandtrackError(
            f"{path}: made by a newer sandtrack (schema {version}, this one reads up to {SCHEMA_VERSION}); upgrade")


@dataclass
class VideoRef:
    camera: str
    path: str
    fingerprint: str
    width: int
    height: int
    fps: float
    frames: int


@dataclass
class VideoProblem:
    camera: str
    path: str
    problem: str  # "missing" | "changed"

    def message(self) -> str:
        if self.problem == "missing":
            return (f"{self.camera} video not found at {self.path}: "
                    f"relink it (sandtrack relink PROJECT --{self.camera} PATH)")
        return (f"{self.camera} video at {self.path} has changed since the project was made: "
                f"relink to confirm (sandtrack relink PROJECT --{self.camera} PATH)")


class Project:
    """An experiment stored in one SQLite file. Use `Project.create` or `Project.open`."""

    def __init__(self, path: str | Path, conn: sqlite3.Connection):
        self.path = Path(path)
        self.conn = conn
        self._open_key = _key(self.path)
        _open_count[self._open_key] = _open_count.get(self._open_key, 0) + 1
        self._edit_id: int | None = None
        self._edit_seq = 0

    # -- opening ---------------------------------------------------------------------------------
    @staticmethod
    def _connect(path: Path) -> sqlite3.Connection:
        conn = sqlite3.connect(str(path), timeout=10.0, isolation_level=None, check_same_thread=False)
        try:
            conn.execute("PRAGMA journal_mode=WAL")
            conn.execute("PRAGMA synchronous=FULL")
            conn.execute("PRAGMA foreign_keys=ON")
        except BaseException:
            conn.close()  # a damaged file fails here: no connection may outlive the failed open
            raise
        return conn

    @classmethod
    def create(cls, path: str | Path, videos: dict[str, str | Path] | None = None,
               overwrite: bool = False, fps: float | None = None) -> Project:
        """`fps`: the frame rate of image folders among `videos` (a video's own rate is read from it)."""
        p = Path(path)
        if p.exists():
            if not overwrite:
                raise SandtrackError(f"{p} already exists (choose another name or delete it)")
            for suffix in ("", "-wal", "-shm"):
                Path(str(p) + suffix).unlink(missing_ok=True)
        if not p.parent.exists():
            raise SandtrackError(f"folder does not exist: {p.parent}")
        try:
            conn = cls._connect(p)
        except sqlite3.Error as exc:
            raise SandtrackError(f"cannot create {p}: {exc}") from None
        proj = cls(p, conn)
        try:
            proj._migrate(0)
            with proj._tx():
                conn.execute("INSERT OR REPLACE INTO meta VALUES ('created', ?)", (str(time.time()),))
            for camera, vpath in (videos or {}).items():
                proj.link_video(camera, vpath, fps)
        except BaseException:
            proj.close()
            raise
        return proj

    @classmethod
    def open(cls, path: str | Path) -> Project:
        p = Path(path)
        if not p.is_file():
            raise SandtrackError(f"project file not found: {p}")
        # Closing ANY descriptor of a file drops all of this process's POSIX locks on it, SQLite's
        # included; another process could then checkpoint and delete the WAL under a live
        # connection (its later commits would be lost). So the header is only read when this
        # process has no connection to the file yet.
        if _open_count.get(_key(p), 0) == 0:
            try:
                with p.open("rb") as fh:
                    head = fh.read(16)
            except OSError as exc:
                raise SandtrackError(f"cannot read {p}: {exc.strerror}") from None
            if head != b"SQLite format 3\x00":
                raise SandtrackError(f"{p}: not a sandtrack project (not an SQLite file)")
        try:
            conn = cls._connect(p)
        except _DAMAGE as exc:
            raise _open_error(p, exc) from None
        try:
            version = cls._read_version(conn)
            _check_version(p, version)
            proj = cls(p, conn)
        except BaseException as exc:
            conn.close()
            if isinstance(exc, _DAMAGE):
                raise _open_error(p, exc) from None
            if isinstance(exc, ValueError):
                raise SandtrackError(f"{p}: project file is damaged (bad schema version)") from None
            raise
        if version < SCHEMA_VERSION:
            try:
                proj._migrate(version)
            except BaseException as exc:
                proj.close()
                if isinstance(exc, _DAMAGE):
                    raise _open_error(p, exc) from None
                raise
        return proj

    @staticmethod
    def _read_version(conn: sqlite3.Connection) -> int | None:
        has_meta = conn.execute("SELECT 1 FROM sqlite_master WHERE type='table' AND name='meta'").fetchone()
        if not has_meta:
            return None
        row = conn.execute("SELECT value FROM meta WHERE key='schema_version'").fetchone()
        return int(row[0]) if row else None

    def _migrate(self, from_version: int) -> None:
        with self._tx():
            for v in range(from_version, SCHEMA_VERSION):
                self._run_script(MIGRATIONS[v])
            self.conn.execute("INSERT OR REPLACE INTO meta VALUES ('schema_version', ?)", (str(SCHEMA_VERSION),))

    def _run_script(self, script: str) -> None:
        for stmt in script.split(";"):
            if stmt.strip():
                self.conn.execute(stmt)

    def close(self) -> None:
        if self._open_key is not None:
            _open_count[self._open_key] = max(_open_count.get(self._open_key, 1) - 1, 0)
            self._open_key = None
        with suppress(sqlite3.Error):
            self.conn.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    @contextmanager
    def _tx(self):
        try:
            self.conn.execute("BEGIN IMMEDIATE")
        except sqlite3.OperationalError as exc:
            raise SandtrackError(f"{self.path}: cannot write ({exc})") from None
        try:
            yield
            self.conn.execute("COMMIT")
        except BaseException:
            if self.conn.in_transaction:  # SQLite may already have rolled back (e.g. disk full)
                self.conn.execute("ROLLBACK")
            raise

    def _write(self, fn):
        """Run fn() in a transaction, turning disk/permission errors into one-line messages."""
        try:
            with self._tx():
                return fn()
        except sqlite3.IntegrityError:
            raise
        except sqlite3.DatabaseError as exc:
            msg = str(exc)
            if "readonly" in msg:
                msg = "the project file is read-only"
            elif "full" in msg:
                msg = "the disk is full"
            raise SandtrackError(f"{self.path}: cannot save ({msg}); nothing was changed") from None

    @contextmanager
    def _reading(self):
        """Damage inside the file only shows when its pages are read: one line instead of a traceback."""
        try:
            yield
        except (*_DAMAGE, pd.errors.DatabaseError, json.JSONDecodeError) as exc:
            cause = exc.__cause__ if isinstance(exc.__cause__, sqlite3.Error) else exc
            raise SandtrackError(f"{self.path}: cannot read the project file, it is damaged "
                                 f"({str(cause).splitlines()[0][:200]})") from None

    # -- videos --------------------------------------------------------------------------------
    def link_video(self, camera: str, path: str | Path, fps: float | None = None) -> VideoRef:
        """`fps`: an image folder's frame rate; None keeps the camera's stored one (50 for a new folder)."""
        from .video import FrameSource, fingerprint

        p = Path(path).resolve()
        if fps is None and camera in self.videos():
            fps = self.videos()[camera].fps
        with FrameSource(p, cache_mb=64, fps=fps) as src:
            ref = VideoRef(camera, str(p), fingerprint(p), src.width, src.height, src.fps, len(src))
        self._write(lambda: self.conn.execute(
            "INSERT OR REPLACE INTO videos VALUES (?,?,?,?,?,?,?)",
            (ref.camera, ref.path, ref.fingerprint, ref.width, ref.height, ref.fps, ref.frames)))
        return ref

    def videos(self) -> dict[str, VideoRef]:
        with self._reading():
            rows = self.conn.execute(
                "SELECT camera, path, fingerprint, width, height, fps, frames FROM videos ORDER BY rowid").fetchall()
        for r in rows:
            if not (all(isinstance(v, str) for v in r[:3]) and all(isinstance(v, (int, float)) for v in r[3:])):
                raise SandtrackError(f"{self.path}: cannot read the project file, its list of videos is damaged")
        return {r[0]: VideoRef(*r) for r in rows}

    def cameras(self) -> list[str]:
        order = {"side": 0, "front": 1}
        return sorted(self.videos(), key=lambda c: (order.get(c, 2), c))

    def video_problems(self, check_content: bool = True) -> list[VideoProblem]:
        from .video import fingerprint

        out = []
        for ref in self.videos().values():
            p = Path(ref.path)
            if not p.exists():
                out.append(VideoProblem(ref.camera, ref.path, "missing"))
            elif check_content and fingerprint(p) != ref.fingerprint:
                out.append(VideoProblem(ref.camera, ref.path, "changed"))
        return out

    def open_sources(self, cache_mb: float = 256) -> dict:
        """FrameSource per camera; raises one clear error if a video moved or changed."""
        from .video import FrameSource

        problems = self.video_problems()
        if problems:
            raise SandtrackError("; ".join(p.message() for p in problems))
        refs = self.videos()
        return {c: FrameSource(refs[c].path, cache_mb=cache_mb, fps=refs[c].fps) for c in self.cameras()}

    # -- facts about the file (not edits: undo leaves them) -----------------------------------
    def meta(self, key: str) -> str | None:
        with self._reading():
            row = self.conn.execute("SELECT value FROM meta WHERE key=?", (key,)).fetchone()
        return None if row is None else str(row[0])

    def set_meta(self, key: str, value: str) -> None:
        if key in ("schema_version", "created"):
            raise SandtrackError(f"meta key {key!r} is the store's own")
        self._write(lambda: self.conn.execute("INSERT OR REPLACE INTO meta VALUES (?, ?)", (key, str(value))))

    # -- settings ------------------------------------------------------------------------------
    def get(self, key: str, default=None):
        with self._reading():
            row = self.conn.execute("SELECT value FROM settings WHERE key=?", (key,)).fetchone()
            if row is not None and not isinstance(row[0], str):
                raise SandtrackError(f"{self.path}: setting {key!r} is damaged")
            return json.loads(row[0]) if row else default

    def set(self, key: str, value, description: str | None = None) -> None:
        """Set a setting (JSON-serialisable) as one undoable edit."""
        after = json.dumps(value)
        self._write(lambda: self._set_logged(self._new_edit("setting", description or f"set {key}"), 0, key, after))

    def _set_logged(self, edit_id: int, seq: int, key: str, after: str) -> None:
        """Inside a write: a setting's new JSON value, its old one logged in edit `edit_id` (row `seq`)."""
        before = self.conn.execute("SELECT value FROM settings WHERE key=?", (key,)).fetchone()
        self._log_row(edit_id, seq, "settings", key, before[0] if before else None, after)
        self.conn.execute("INSERT OR REPLACE INTO settings VALUES (?, ?)", (key, after))

    @property
    def sync_offset_s(self) -> float:
        return float(self.get("sync_offset_s", 0.0))

    def sync_confirmed(self) -> bool:
        """True once a sync offset was stored (measured, typed in, or 0 set on purpose); before that
        `sync_offset_s` is a default of 0, which is wrong for cameras started by hand."""
        return self.get("sync_offset_s") is not None

    def calibration(self):
        from .camera import Calibration

        text = self.get("calibration")
        if text is not None and not isinstance(text, str):
            raise SandtrackError(f"{self.path}: the stored calibration is damaged")
        return Calibration.from_toml(text, source=f"{self.path} calibration") if text else None

    def set_calibration(self, calibration) -> None:
        self.set("calibration", calibration.to_toml(), "set calibration")

    def board(self):
        from .board import board_from_dict

        d = self.get("board")
        return board_from_dict(d) if d else None

    # -- markers -------------------------------------------------------------------------------
    def markers(self) -> pd.DataFrame:
        with self._reading():
            return pd.read_sql_query("SELECT id, label FROM markers ORDER BY id", self.conn)

    def add_marker(self, label: str | None = None, marker_id: int | None = None) -> int:
        def fn():
            mid = marker_id
            if mid is None:
                row = self.conn.execute("SELECT COALESCE(MAX(id), 0) + 1 FROM markers").fetchone()
                mid = int(row[0])
            lab = label if label is not None else str(mid)
            eid = self._new_edit("marker", f"add marker {lab}")
            old = self.conn.execute("SELECT label FROM markers WHERE id=?", (mid,)).fetchone()
            self._log_row(eid, 0, "markers", str(mid), json.dumps(old[0]) if old else None, json.dumps(lab))
            self.conn.execute("INSERT OR REPLACE INTO markers VALUES (?, ?)", (mid, lab))
            return mid

        return self._write(fn)

    def rename_marker(self, marker_id: int, label: str) -> None:
        """Give a marker a new label (the name shown everywhere; its id stays), as one undoable edit."""
        label = str(label).strip()
        if not label or len(label) > LABEL_MAX or not label.isprintable():
            raise SandtrackError(f"a marker label is 1-{LABEL_MAX} printable characters, not {label!r}")

        def fn():
            old = self.conn.execute("SELECT label FROM markers WHERE id=?", (marker_id,)).fetchone()
            if old is None:
                raise SandtrackError(f"no marker {marker_id}")
            eid = self._new_edit("marker", f"rename marker {old[0]} to {label}")
            self._log_row(eid, 0, "markers", str(marker_id), json.dumps(old[0]), json.dumps(label))
            self.conn.execute("UPDATE markers SET label=? WHERE id=?", (label, marker_id))

        self._write(fn)

    def delete_marker(self, marker_id: int) -> None:
        """Delete a marker and all its points (undoable)."""
        def fn():
            eid = self._new_edit("marker", f"delete marker {marker_id}")
            old = self.conn.execute("SELECT label FROM markers WHERE id=?", (marker_id,)).fetchone()
            seq = self._log_point_deletions(eid, "marker=?", (marker_id,), 0)
            self._log_row(eid, seq, "markers", str(marker_id), json.dumps(old[0]) if old else None, None)
            self.conn.execute("DELETE FROM points WHERE marker=?", (marker_id,))
            self.conn.execute("DELETE FROM markers WHERE id=?", (marker_id,))

        self._write(fn)

    # -- points --------------------------------------------------------------------------------
    def points(self, frame: int | None = None, camera: str | None = None, marker: int | None = None,
               frames: tuple[int, int] | None = None) -> pd.DataFrame:
        """Points as a DataFrame with POINT_COLUMNS (frame = that camera's own frame index)."""
        where, args = [], []
        for col, val in (("frame", frame), ("camera", camera), ("marker", marker)):
            if val is not None:
                where.append(f"{col}=?")
                args.append(val)
        if frames is not None:
            where.append("frame BETWEEN ? AND ?")
            args.extend(frames)
        sql = f"SELECT {', '.join(POINT_COLUMNS)} FROM points"
        if where:
            sql += " WHERE " + " AND ".join(where)
        sql += " ORDER BY marker, camera, frame"
        with self._reading():
            return pd.read_sql_query(sql, self.conn, params=args)

    def set_points(self, rows, description: str = "edit points", kind: str = "points") -> int:
        """Insert or replace point rows (DataFrame or iterable of dicts/tuples in POINT_COLUMNS
        order) as one undoable edit, committed at once. Returns the edit id."""
        with self.edit(description, kind) as ed:
            ed.write(rows)
        return ed.edit_id

    def delete_points(self, marker: int, camera: str | None = None, frames: tuple[int, int] | None = None,
                      description: str | None = None) -> int:
        def fn():
            eid = self._new_edit("points", description or f"delete points of marker {marker}")
            where, args = "marker=?", [marker]
            if camera is not None:
                where += " AND camera=?"
                args.append(camera)
            if frames is not None:
                where += " AND frame BETWEEN ? AND ?"
                args.extend(frames)
            self._log_point_deletions(eid, where, tuple(args), 0)
            self.conn.execute(f"DELETE FROM points WHERE {where}", args)
            return eid

        return self._write(fn)

    @contextmanager
    def edit(self, description: str, kind: str = "points", sync_each_write: bool = True):
        """One undoable edit whose rows may be written in several commits (e.g. while tracking):
        every `write` is committed at once, so an interrupted run keeps what it wrote.

        sync_each_write=False (long runs writing many chunks): a commit does not wait for the disk.
        A killed process still loses nothing, as the committed journal is in the operating system's
        hands; only a power cut could take back the last chunks. The file is synced to disk once,
        when the edit ends."""
        ed = _Edit(self, description, kind)
        if sync_each_write:
            yield ed
            return
        self._set_synchronous("NORMAL")
        try:
            yield ed
        finally:
            self._set_synchronous("FULL")
            with suppress(sqlite3.DatabaseError):  # the journal holds the rows either way
                self.conn.execute("PRAGMA wal_checkpoint(PASSIVE)")  # syncs the journal, then the file

    def _set_synchronous(self, mode: str) -> None:
        with suppress(sqlite3.DatabaseError):
            self.conn.execute(f"PRAGMA synchronous={mode}")

    def _log_point_deletions(self, eid: int, where: str, args: tuple, seq: int) -> int:
        rows = self.conn.execute(f"SELECT {', '.join(POINT_COLUMNS)} FROM points WHERE {where}", args).fetchall()
        for r in rows:
            self._log_row(eid, seq, "points", json.dumps(list(r[:3])), _dumps_row(r[3:]), None)
            seq += 1
        return seq

    # -- edit log ------------------------------------------------------------------------------
    def _new_edit(self, kind: str, description: str) -> int:
        # A new edit discards the redo stack.
        self.conn.execute("DELETE FROM edit_rows WHERE edit_id IN (SELECT id FROM edits WHERE undone=1)")
        self.conn.execute("DELETE FROM edits WHERE undone=1")
        cur = self.conn.execute("INSERT INTO edits (kind, description, created) VALUES (?,?,?)",
                                (kind, description, time.time()))
        return int(cur.lastrowid)

    def _log_row(self, eid: int, seq: int, table: str, key: str, before: str | None, after: str | None) -> None:
        self.conn.execute("INSERT INTO edit_rows VALUES (?,?,?,?,?,?)", (eid, seq, table, key, before, after))

    def history(self, limit: int = 50) -> pd.DataFrame:
        with self._reading():
            return pd.read_sql_query(
                "SELECT id, kind, description, created, undone FROM edits ORDER BY id DESC LIMIT ?",
                self.conn, params=(limit,))

    def can_undo(self) -> bool:
        return self.conn.execute("SELECT 1 FROM edits WHERE undone=0 LIMIT 1").fetchone() is not None

    def can_redo(self) -> bool:
        return self.conn.execute("SELECT 1 FROM edits WHERE undone=1 LIMIT 1").fetchone() is not None

    def undo(self) -> str | None:
        """Undo the latest edit; returns its description, or None if there is nothing to undo."""
        with self._reading():
            row = self.conn.execute(
                "SELECT id, description FROM edits WHERE undone=0 ORDER BY id DESC LIMIT 1").fetchone()
        if row is None:
            return None

        def fn():
            self._apply_checked(row[0], "before")
            self.conn.execute("UPDATE edits SET undone=1 WHERE id=?", (row[0],))

        self._write(fn)
        return row[1]

    def redo(self) -> str | None:
        with self._reading():
            row = self.conn.execute(
                "SELECT id, description FROM edits WHERE undone=1 ORDER BY id ASC LIMIT 1").fetchone()
        if row is None:
            return None

        def fn():
            self._apply_checked(row[0], "after")
            self.conn.execute("UPDATE edits SET undone=0 WHERE id=?", (row[0],))

        self._write(fn)
        return row[1]

    def _apply_checked(self, eid: int, side: str) -> None:
        try:
            self._apply(eid, side)
        except (ValueError, TypeError, sqlite3.IntegrityError, sqlite3.ProgrammingError):  # a tampered log
            raise SandtrackError(f"{self.path}: edit {eid} of the edit log is damaged; nothing was changed") from None

    def _apply(self, eid: int, side: str) -> None:
        order = "DESC" if side == "before" else "ASC"
        rows = self.conn.execute(
            f"SELECT seq, table_name, key, {side}, after IS NULL FROM edit_rows WHERE edit_id=? ORDER BY seq {order}",
            (eid,)).fetchall()
        for seq, table, key, value, no_after in rows:
            if table == "points_batch":
                keys = json.loads(key)
                if side == "before" and no_after:
                    self._keep_after(eid, seq, keys)
                self._apply_batch(keys, json.loads(value), reverse=side == "before")
            elif table == "points":
                f, c, m = json.loads(key)
                if value is None:
                    self.conn.execute(_DELETE_POINT, (f, c, m))
                else:
                    self.conn.execute(_PUT_POINT, (f, c, m, *json.loads(value)))
            elif table == "markers":
                if value is None:
                    self.conn.execute("DELETE FROM markers WHERE id=?", (int(key),))
                else:
                    self.conn.execute("INSERT OR REPLACE INTO markers VALUES (?, ?)", (int(key), json.loads(value)))
            elif table == "settings":
                if value is None:
                    self.conn.execute("DELETE FROM settings WHERE key=?", (key,))
                else:
                    self.conn.execute("INSERT OR REPLACE INTO settings VALUES (?, ?)", (key, value))

    def _keep_after(self, eid: int, seq: int, keys: list) -> None:
        """Log the values a 'points_batch' row wrote, for redo, as it is undone: undo goes back through
        the edits and their rows in reverse order, so the points hold exactly those values now."""
        if not isinstance(keys, list) or not all(isinstance(k, list) and len(k) == 3 for k in keys):
            raise ValueError("points_batch row with malformed keys")
        now = _existing_values(self.conn, [tuple(k) for k in keys])
        after = json.dumps([now.get(tuple(k)) for k in keys], default=str)
        self.conn.execute("UPDATE edit_rows SET after=? WHERE edit_id=? AND seq=?", (after, eid, seq))

    def _apply_batch(self, keys: list, values: list, reverse: bool) -> None:
        """One 'points_batch' log row's side: each key's values, or its deletion where null."""
        if not isinstance(keys, list) or not isinstance(values, list) or len(keys) != len(values):
            raise ValueError("points_batch row with keys and values of different lengths")
        pairs = list(zip(keys, values, strict=True))
        if reverse:
            pairs.reverse()
        # Within one write every key's "before" is the same and its "after" is never null: deleting
        # first, then writing in order, is the same as applying the entries one by one.
        self.conn.executemany(_DELETE_POINT, [tuple(k) for k, v in pairs if v is None])
        self.conn.executemany(_PUT_POINT, [(*k, *v) for k, v in pairs if v is not None])


class _Edit:
    """Rows written through one edit; each `write` is its own committed transaction."""

    def __init__(self, project: Project, description: str, kind: str):
        self.project = project
        self.description = description
        self.kind = kind
        self.edit_id: int | None = None
        self.seq = 0

    def write(self, rows) -> int:
        """Insert or replace point rows as part of this edit, in one committed transaction, logged as
        one edit_rows row ('points_batch': the points' keys and values before)."""
        records = list(_as_point_tuples(rows))
        if not records:
            return 0
        conn = self.project.conn

        def fn():
            if self.edit_id is None:
                self.edit_id = self.project._new_edit(self.kind, self.description)
            olds = _existing_values(conn, records)
            keys = json.dumps([r[:3] for r in records])
            before = json.dumps([olds.get(r[:3]) for r in records], default=str)
            # "after" is logged when the edit is undone (Project._keep_after): not needed before then.
            self.project._log_row(self.edit_id, self.seq, "points_batch", keys, before, None)
            self.seq += 1
            conn.executemany(_PUT_POINT, records)

        self.project._write(fn)
        return len(records)

    def delete(self, keys) -> int:
        """Delete points by (frame, camera, marker) as part of this edit (undone with it), in one
        committed transaction, logged as one edit_rows row ('points_batch': the points' keys and values
        before; their "after", none, is logged when the edit is undone, as for `write`)."""
        keys = list(dict.fromkeys((int(f), str(c), int(m)) for f, c, m in keys))
        if not keys:
            return 0
        conn = self.project.conn

        def fn():
            olds = _existing_values(conn, keys)
            there = [k for k in keys if k in olds]
            if not there:
                return
            if self.edit_id is None:
                self.edit_id = self.project._new_edit(self.kind, self.description)
            before = json.dumps([olds[k] for k in there], default=str)
            self.project._log_row(self.edit_id, self.seq, "points_batch", json.dumps(there), before, None)
            self.seq += 1
            conn.executemany(_DELETE_POINT, there)

        self.project._write(fn)
        return len(keys)

    def set(self, key: str, value) -> None:
        """Set a setting (JSON-serialisable) as part of this edit (undone with it)."""
        after = json.dumps(value)

        def fn():
            if self.edit_id is None:
                self.edit_id = self.project._new_edit(self.kind, self.description)
            self.project._set_logged(self.edit_id, self.seq, key, after)
            self.seq += 1

        self.project._write(fn)

    def add_markers(self, marker_ids) -> int:
        """Add markers (label = id) that do not exist yet, as part of this edit, in one transaction."""
        conn = self.project.conn
        ids = sorted({int(m) for m in marker_ids})

        def fn():
            have = {int(r[0]) for r in conn.execute("SELECT id FROM markers")}
            new = [m for m in ids if m not in have]
            if not new:
                return 0
            if self.edit_id is None:
                self.edit_id = self.project._new_edit(self.kind, self.description)
            for m in new:
                self.project._log_row(self.edit_id, self.seq, "markers", str(m), None, json.dumps(str(m)))
                self.seq += 1
            conn.executemany("INSERT INTO markers VALUES (?, ?)", [(m, str(m)) for m in new])
            return len(new)

        return self.project._write(fn)

    def delete_marker(self, marker_id: int) -> None:
        """Remove a marker's row (its points are this edit's business) as part of this edit."""
        conn = self.project.conn

        def fn():
            if self.edit_id is None:
                self.edit_id = self.project._new_edit(self.kind, self.description)
            old = conn.execute("SELECT label FROM markers WHERE id=?", (int(marker_id),)).fetchone()
            if old is None:
                return
            self.project._log_row(self.edit_id, self.seq, "markers", str(int(marker_id)), json.dumps(old[0]), None)
            self.seq += 1
            conn.execute("DELETE FROM markers WHERE id=?", (int(marker_id),))

        self.project._write(fn)


def _existing_values(conn, records) -> dict:
    """Stored values of the records' points: (frame, camera, marker) -> row of _POINT_VALUES.
    One range query per (camera, marker) instead of one query per point."""
    spans: dict[tuple, list] = {}
    for r in records:
        s = spans.get((r[1], r[2]))
        if s is None:
            spans[(r[1], r[2])] = [r[0], r[0]]
        elif r[0] < s[0]:
            s[0] = r[0]
        elif r[0] > s[1]:
            s[1] = r[0]
    wanted = {r[:3] for r in records}
    out = {}
    sql = (f"SELECT frame, {', '.join(_POINT_VALUES)} FROM points "
           f"WHERE marker=? AND camera=? AND frame BETWEEN ? AND ?")
    for (c, m), (a, b) in spans.items():
        for row in conn.execute(sql, (m, c, a, b)):
            k = (row[0], c, m)
            if k in wanted:
                out[k] = row[1:]
    return out


def _as_point_tuples(rows) -> Iterable[tuple]:
    if isinstance(rows, pd.DataFrame):
        df = rows.copy()
        for col in ("score", "psr", "colour_frac"):
            if col not in df:
                df[col] = np.nan
        rows = df[POINT_COLUMNS].itertuples(index=False, name=None)
    for r in rows:
        if isinstance(r, dict):
            r = tuple(r.get(c) for c in POINT_COLUMNS)
        if type(r) is not tuple or len(r) != 9:
            r = tuple(r)
            r = r[:9] + (None,) * (9 - len(r))
        f, c, m, x, y, status, score, psr, colour = r
        if status not in STATUSES:
            raise SandtrackError(f"unknown point status {status!r} (one of {', '.join(STATUSES)})")
        if type(x) is float and type(y) is float and type(score) is float and type(psr) is float \
                and type(colour) is float:  # the tracker's rows: v - v == 0 only for finite floats
            yield (int(f), str(c), int(m), x if x - x == 0.0 else None, y if y - y == 0.0 else None, status,
                   score if score - score == 0.0 else None, psr if psr - psr == 0.0 else None,
                   colour if colour - colour == 0.0 else None)
        else:
            yield (int(f), str(c), int(m), _num(x), _num(y), status, _num(score), _num(psr), _num(colour))


def _dumps_row(values) -> str:
    """A row's values for the edit log (a value of a foreign type, e.g. a BLOB, is kept as its text)."""
    return json.dumps(list(values), default=str)


def _num(v):
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None


def project_default_name(videos: Sequence[str]) -> str:
    return os.path.splitext(os.path.basename(videos[0]))[0] + ".sandtrack"
