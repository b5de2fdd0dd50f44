"""Cameras the service learns, kept in SQLite (`Settings.camera_db`), and the focal length a
request knows from one (`known_focal`).

The store is one table of JSON rows; every call opens its own connection (SQLite serialises
the writers of all worker processes; WAL lets readers go on meanwhile), so cameras survive a
restart and every process sees them. `create` counts and inserts in one IMMEDIATE
transaction: concurrent creators cannot pass `max_cameras` together.

A camera's intrinsics are px of images `width` x `height`; it answers an image of another
size with them scaled by the ratio of the longer sides (a portrait photo of a landscape
camera is the same lens turned; `service.pipeline.focal.KnownFocal.camera`). A camera
without a size uses its fx as is.
"""

from __future__ import annotations

import json
import logging
import os
import secrets
import sqlite3
import stat
import threading
from collections.abc import Iterator
from contextlib import closing, contextmanager, suppress
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from service.cameras.schema import CameraIn, CameraOut
from service.metrics import Metrics
from service.pipeline.focal import KnownFocal

log = logging.getLogger("uvicorn.error.pose")  # printed by uvicorn's handlers

_SCHEMA = (
    "CREATE TABLE IF NOT EXISTS cameras (id TEXT PRIMARY KEY, created TEXT NOT NULL, "
    "body TEXT NOT NULL)"
)


class CameraNotFound(LookupError):
    """No stored camera has that id."""


class CameraStoreFull(RuntimeError):
    """The store holds `max_cameras` cameras already."""


class CameraStoreError(RuntimeError):
    """The database cannot be opened or written (path, permissions, a corrupt file:
    `damaged`)."""

    def __init__(self, message: str, damaged: bool = False) -> None:
        super().__init__(message)
        self.damaged = damaged


class CameraCorrupt(ValueError):
    """The row of a camera does not parse or validate (written by hand, by another version, or
    damaged): its id answers this until it is deleted."""

    def __init__(self, camera_id: str, reason: str) -> None:
        super().__init__(  # what to do first: a stream's close reason keeps 123 bytes
            f"camera {camera_id!r} is stored corrupt: DELETE /v1/cameras/{camera_id} clears "
            f"it ({reason})"
        )
        self.camera_id, self.reason = camera_id, reason


def known_focal(camera: CameraOut) -> KnownFocal:
    """A stored camera's intrinsics as a request knows them (`camera=`). A lens learned from
    photos by their corners alone (no principal point: `service.core.calibration`) is
    `lens_learned`, each image fitting its own; one calibrated from their features is used
    as a registered camera's."""
    size = None if camera.width is None or camera.height is None else (camera.width, camera.height)
    dist = None if camera.dist is None else tuple(camera.dist)
    learned = camera.source == "photos" and camera.cx is None
    return KnownFocal(camera.fx, "camera", size, camera.fy, camera.cx, camera.cy, dist, learned)


def new_id() -> str:
    return "c-" + secrets.token_hex(4)


@dataclass(frozen=True)
class FileIdentity:
    """What the store's file was when this process last used it: device, inode and size."""

    device: int
    inode: int
    size: int

    @classmethod
    def of(cls, path: Path) -> FileIdentity | None:
        try:
            st = path.stat()
        except OSError:
            return None
        return cls(st.st_dev, st.st_ino, st.st_size)

    def change(self, now: FileIdentity | None) -> str | None:
        """How the file changed since (SQLite never shrinks it, nor swaps it), or None."""
        if now is None:
            return "was removed (a new, empty store is made)"
        if (now.device, now.inode) != (self.device, self.inode):
            return f"was replaced by another file (inode {self.inode} -> {now.inode})"
        if now.size < self.size:
            return f"was truncated ({self.size} -> {now.size} bytes)"
        return None


class CameraStore:
    """The cameras in the SQLite file `path`, at most `max_cameras` of them. Rows that do not
    parse or validate are skipped by `list`, CameraCorrupt for `get`, deleted as any other;
    each is logged once per process and counted in `metrics`. A file that was removed,
    replaced or truncated under the process is logged (error) when it is next opened."""

    def __init__(self, path: Path, max_cameras: int, metrics: Metrics | None = None) -> None:
        self.path, self.max_cameras, self.metrics = path, max_cameras, metrics
        self._lock = threading.Lock()
        self._seen: FileIdentity | None = None
        self._reported: set[str] = set()

    def _watch(self) -> None:
        """Log (once) a change of the file under the process since its last use."""
        now = FileIdentity.of(self.path)
        with self._lock:
            change = None if self._seen is None else self._seen.change(now)
            self._seen = now
        if change is not None:
            log.error(
                "camera store %s %s while the service used it: the cameras it held are "
                "gone from this service unless the file is restored",
                self.path,
                change,
            )
            self._count("store_changed")

    def _count(self, event: str) -> None:
        if self.metrics is not None:
            self.metrics.camera_store.labels(event).inc()

    @contextmanager
    def _db(self) -> Iterator[sqlite3.Connection]:
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._watch()
            with closing(sqlite3.connect(self.path, timeout=10.0, isolation_level=None)) as db:
                db.execute("PRAGMA journal_mode=WAL")
                db.execute(_SCHEMA)
                yield db
            with self._lock:
                self._seen = FileIdentity.of(self.path)
        except sqlite3.Error as exc:
            damaged = isinstance(exc, sqlite3.DatabaseError) and any(
                word in str(exc) for word in ("malformed", "not a database")
            )
            raise CameraStoreError(_sqlite_problem(self.path, exc), damaged) from None
        except OSError as exc:
            text = f"camera store {self.path}: {exc.strerror or exc}"
            raise CameraStoreError(f"{text}{_unwritable_hint(self.path)}") from None

    def check_at_start(self) -> None:
        """`check`, its outcome logged; never raises (the service starts all the same and the
        camera routes answer 503 with the reason)."""
        try:
            self.check()
        except CameraStoreError as exc:
            log.error("%s", exc)

    def check(self) -> list[str]:
        """At start: `PRAGMA quick_check` and every row read; the problems found (each
        logged), [] for a sound store. CameraStoreError when it cannot be opened or read (a
        damaged file: counted as integrity_failed)."""
        try:
            with self._db() as db:
                verdict = [row[0] for row in db.execute("PRAGMA quick_check").fetchall()]
                rows = db.execute("SELECT id, created, body FROM cameras").fetchall()
        except CameraStoreError as exc:
            if exc.damaged:
                self._count("integrity_failed")
            raise
        problems = [] if verdict == ["ok"] else [f"PRAGMA quick_check: {'; '.join(verdict)}"]
        if problems:
            log.error(
                "camera store %s fails its integrity check (%s): move it away to start an "
                "empty one, or restore it from a backup",
                self.path,
                problems[0][:500],
            )
            self._count("integrity_failed")
        for row in rows:
            try:
                self._camera(row, "check")
            except CameraCorrupt as exc:
                problems.append(str(exc))
        log.info(
            "camera store %s: %d cameras, %d unusable rows, integrity %s",
            self.path,
            len(rows),
            len(problems) - (verdict != ["ok"]),
            "ok" if verdict == ["ok"] else "FAILED",
        )
        return problems

    def _camera(self, row: tuple[str, str, str], operation: str) -> CameraOut:
        """The camera of a row, or CameraCorrupt (logged once per id, counted each time)."""
        try:
            return _camera(row)
        except CameraCorrupt as exc:
            if self.metrics is not None:
                self.metrics.camera_corrupt.labels(operation).inc()
            with self._lock:
                first = exc.camera_id not in self._reported
                self._reported.add(exc.camera_id)
            if first:
                log.error("camera store %s: %s", self.path, exc)
            raise

    def create(self, fields: dict[str, Any]) -> CameraOut:
        """Store a camera of `fields` (CameraOut's, without id and created) -> it;
        CameraStoreFull when the store is full."""
        created = datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
        camera = CameraOut(id=new_id(), created=created, **fields)
        body = camera.model_dump_json(exclude={"id", "created"})
        with self._db() as db:
            db.execute("BEGIN IMMEDIATE")
            try:
                (count,) = db.execute("SELECT COUNT(*) FROM cameras").fetchone()
                if count >= self.max_cameras:
                    raise CameraStoreFull(
                        f"the camera store holds {count} cameras, its limit "
                        f"(POSE_MAX_CAMERAS): delete some first"
                    )
                db.execute(
                    "INSERT INTO cameras (id, created, body) VALUES (?, ?, ?)",
                    (camera.id, created, body),
                )
                db.execute("COMMIT")
            except BaseException:
                db.execute("ROLLBACK")
                raise
        return camera

    def create_from(self, given: CameraIn, name: str | None = None) -> CameraOut:
        """Store a camera of the intrinsics `given` (named by its `name`, else `name`)."""
        fields = given.model_dump()
        fields["name"] = fields["name"] or name
        return self.create(
            {**fields, "source": "intrinsics", "photos_used": 0, "residual_px": None}
        )

    def get(self, camera_id: str, operation: str = "get") -> CameraOut:
        """The camera `camera_id`; CameraNotFound when there is none, CameraCorrupt when its
        row does not parse or validate."""
        with self._db() as db:
            row = db.execute(
                "SELECT id, created, body FROM cameras WHERE id = ?", (camera_id,)
            ).fetchone()
        if row is None:
            raise CameraNotFound(f"no camera with id {camera_id!r} (GET /v1/cameras lists them)")
        return self._camera(row, operation)

    def list(self) -> list[CameraOut]:
        """All cameras, newest first; rows that do not parse or validate are left out."""
        with self._db() as db:
            rows = db.execute(
                "SELECT id, created, body FROM cameras ORDER BY created DESC, rowid DESC"
            ).fetchall()
        cameras = []
        for row in rows:
            with suppress(CameraCorrupt):
                cameras.append(self._camera(row, "list"))
        return cameras

    def delete(self, camera_id: str) -> None:
        """Remove the camera `camera_id` (a corrupt one too); CameraNotFound when there is
        none."""
        with self._db() as db:
            gone = db.execute("DELETE FROM cameras WHERE id = ?", (camera_id,)).rowcount
        if not gone:
            raise CameraNotFound(f"no camera with id {camera_id!r} (GET /v1/cameras lists them)")
        with self._lock:
            self._reported.discard(camera_id)


def _unwritable_hint(path: Path) -> str:
    """What to do when the store's folder cannot be written by this process."""
    folder, uid = path.parent, os.getuid()
    try:
        st = folder.stat()
    except OSError:
        return f" (make {folder} exist and be writable by uid {uid}, or set POSE_CAMERA_DB)"
    if os.access(folder, os.W_OK | os.X_OK):
        return ""
    return (
        f" ({folder} belongs to uid {st.st_uid} with mode {stat.S_IMODE(st.st_mode):o}: uid {uid} "
        f"cannot make the database and its -wal and -shm files there; mount a volume at "
        f"{folder} (docker/podman run -v pose-data:{folder}) or a tmpfs owned by uid {uid} "
        f"(podman --tmpfs {folder}:U, docker --tmpfs {folder}:uid={uid}), or set "
        f"POSE_CAMERA_DB to a writable place: docs/service.md, The container)"
    )


def _sqlite_problem(path: Path, exc: sqlite3.Error) -> str:
    """The message of an SQLite error, with what to do where SQLite's own says little."""
    text = f"camera store {path}: {exc}"
    said = str(exc)
    if "not a database" in said:
        return f"{text} (the file is not an SQLite database: move it away or restore it)"
    if "malformed" in said:
        return f"{text} (the file is damaged: move it away or restore it from a backup)"
    if "unable to open" in said or "readonly" in said or "disk I/O" in said:
        return f"{text}{_unwritable_hint(path)}"
    return text


def _camera(row: tuple[str, str, str]) -> CameraOut:
    """A row -> its camera; CameraCorrupt saying why it is not one."""
    camera_id = str(row[0])
    try:
        body = json.loads(row[2])
    except (ValueError, TypeError) as exc:  # not JSON, or not text
        raise CameraCorrupt(camera_id, f"its JSON does not parse: {exc}") from None
    if not isinstance(body, dict):
        raise CameraCorrupt(camera_id, f"its JSON is a {type(body).__name__}, not an object")
    try:
        return CameraOut.model_validate({**body, "id": camera_id, "created": row[1]})
    except ValidationError as exc:
        problems = "; ".join(
            f"{'.'.join(str(p) for p in e['loc']) or 'body'}: {e['msg']}" for e in exc.errors()
        )
        raise CameraCorrupt(camera_id, f"it does not validate: {problems}") from None
