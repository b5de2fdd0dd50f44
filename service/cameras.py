"""Cameras the service learns, kept in SQLite (`Settings.camera_db`), and the focal length a
request knows.

The store is one table of JSON rows; every call opens its own connection (SQLite serialises
the writers of all worker processes; WAL lets readers go on meanwhile), so cameras survive a
restart and every process sees them. `create` counts and inserts in one IMMEDIATE
transaction: concurrent creators cannot pass `max_cameras` together.

A camera's intrinsics are px of images `width` x `height`; it answers an image of another
size with them scaled by the ratio of the longer sides (a portrait photo of a landscape
camera is the same lens turned). A camera without a size uses its fx as is.
"""

from __future__ import annotations

import json
import secrets
import sqlite3
from collections.abc import Iterator
from contextlib import closing, contextmanager
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from service.core.pose import Camera
from service.schemas import CameraOut, FocalSource

_SCHEMA = (
    "CREATE TABLE IF NOT EXISTS cameras (id TEXT PRIMARY KEY, created TEXT NOT NULL, "
    "body TEXT NOT NULL)"
)


class CameraNotFound(LookupError):
    """No stored camera has that id."""


class CameraStoreFull(RuntimeError):
    """The store holds `max_cameras` cameras already."""


class CameraStoreError(RuntimeError):
    """The database cannot be opened or written (path, permissions, a corrupt file)."""


@dataclass(frozen=True)
class KnownFocal:
    """A focal length a request knows and where it came from: fx (and optionally fy, the
    principal point, OpenCV's distortion) px of images `size` (W, H) (None: any size);
    `lens_learned`: the distortion was learned from photos (`service.core.calibration`): each
    image fits its own lens instead, which answered more of the ChArUco val frames."""

    fx: float
    source: FocalSource
    size: tuple[int, int] | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    dist: tuple[float, ...] | None = None
    lens_learned: bool = False

    @classmethod
    def of(cls, camera: CameraOut) -> KnownFocal:
        """A stored camera's intrinsics."""
        size = None if camera.width is None or camera.height is None else (
            camera.width, camera.height
        )  # fmt: skip
        dist = None if camera.dist is None else tuple(camera.dist)
        learned = camera.source == "photos"
        return cls(camera.fx, "camera", size, camera.fy, camera.cx, camera.cy, dist, learned)

    @classmethod
    def of_camera(cls, camera: Camera, source: FocalSource = "camera") -> KnownFocal:
        """A calibrated camera (`service.core.pose.Camera`) as a request knows it."""
        return cls(camera.fx, source, camera.size, camera.fy, camera.cx, camera.cy, camera.dist)

    def scale(self, size: tuple[int, int]) -> float:
        """Pixels of an image of `size` (W, H) per pixel of the camera's own images."""
        return 1.0 if self.size is None else max(size) / max(self.size)

    def camera(self, size: tuple[int, int]) -> Camera:
        """The camera for an image of `size` (W, H): the intrinsics scaled to it (a principal
        point given for the camera's own size moves with it; turned with a portrait photo of
        a landscape camera, where it would be the wrong way round, it is the centre)."""
        s = self.scale(size)
        same_way = self.size is None or (size[0] >= size[1]) == (self.size[0] >= self.size[1])
        return Camera(
            self.fx * s,
            size,
            None if self.fy is None else self.fy * s,
            None if self.cx is None or not same_way else self.cx * s,
            None if self.cy is None or not same_way else self.cy * s,
            self.dist,
        )


def new_id() -> str:
    return "c-" + secrets.token_hex(4)


class CameraStore:
    """The cameras in the SQLite file `path`, at most `max_cameras` of them."""

    def __init__(self, path: Path, max_cameras: int) -> None:
        self.path, self.max_cameras = path, max_cameras

    @contextmanager
    def _db(self) -> Iterator[sqlite3.Connection]:
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with closing(sqlite3.connect(self.path, timeout=10.0, isolation_level=None)) as db:
                db.execute("PRAGMA journal_mode=WAL")
                db.execute(_SCHEMA)
                yield db
        except sqlite3.Error as exc:
            raise CameraStoreError(f"camera store {self.path}: {exc}") from None
        except OSError as exc:
            raise CameraStoreError(f"camera store {self.path}: {exc.strerror or exc}") from None

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

    def get(self, camera_id: str) -> CameraOut:
        """The camera `camera_id`; CameraNotFound when there is none."""
        with self._db() as db:
            row = db.execute(
                "SELECT id, created, body FROM cameras WHERE id = ?", (camera_id,)
            ).fetchone()
        if row is None:
            raise CameraNotFound(f"no camera with id {camera_id!r} (GET /v1/cameras lists them)")
        return _camera(row)

    def list(self) -> list[CameraOut]:
        """All cameras, newest first."""
        with self._db() as db:
            rows = db.execute(
                "SELECT id, created, body FROM cameras ORDER BY created DESC, rowid DESC"
            ).fetchall()
        return [_camera(row) for row in rows]

    def delete(self, camera_id: str) -> None:
        """Remove the camera `camera_id`; CameraNotFound when there is none."""
        with self._db() as db:
            gone = db.execute("DELETE FROM cameras WHERE id = ?", (camera_id,)).rowcount
        if not gone:
            raise CameraNotFound(f"no camera with id {camera_id!r} (GET /v1/cameras lists them)")


def _camera(row: tuple[str, str, str]) -> CameraOut:
    return CameraOut(id=row[0], created=row[1], **json.loads(row[2]))
