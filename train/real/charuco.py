"""ChArUco boards: the texture of a profile with a `[charuco]` table, and real video frames
labelled with OpenCV's ChArUco detector and the cameras' own calibration.

Profile table (train/assets/profiles/charuco/profile.toml):

    [charuco]
    squares = [4, 5]               # columns (along x, the width) x rows of squares
    square_cm = 5.4
    marker_cm = 4.05
    dictionary = "DICT_4X4_1000"   # a cv2.aruco predefined dictionary
    inverted = true                # printed white on black (`detectInvertedMarker`)

OpenCV's board frame has its origin at the top-left corner of the board image, x right and
y down; the project's object frame (`service.core.frame`) has its origin at the centre, y up
and z out of the printed face, so a board point (x, y) is object point (x - W/2, H/2 - y).

`label_video_source` labels a staged source (images/ extracted from one camera's video,
`source.json`, `LICENSE`) like `train.real.corpus.label_source` labels a chessboard source:
ChArUco corners at full resolution, the pose from them through the camera's calibration
(`read_camera_array`: caliscope's camera_array.toml), a reprojection gate, and as an
independent check, the pose found by feature matching against the front-on texture
(`train.real.corners.TextureMatcher`), which never sees the detector's corners.
"""

from __future__ import annotations

import tomllib
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from service.core.frame import object_corners
from service.core.regions import pose_class
from train.real.calibration import Camera
from train.real.corners import Correspondences, TextureMatcher
from train.real.corpus import (
    contact_sheet,
    failure_reasons,
    prepare_source,
    store_labelled,
    write_source,
)
from train.real.label import label_from_points

#: Fewest ChArUco corners a pose is computed from.
MIN_CORNERS = 6
#: Largest reprojection RMS (px of the full-size frame, refined pose) of a kept frame.
MAX_RMS_PX = 1.5
#: Texture resolution of `board_texture`.
PX_PER_CM = 20


class CharucoError(ValueError):
    """A profile without a usable [charuco] table, or a bad camera file."""


@dataclass(frozen=True)
class CharucoSpec:
    """A ChArUco board: (columns, rows) of squares, square and marker side (cm), dictionary."""

    squares: tuple[int, int]
    square_cm: float
    marker_cm: float
    dictionary: str
    inverted: bool

    @property
    def size_cm(self) -> tuple[float, float]:
        """(width, height) of the squares, cm."""
        return self.squares[0] * self.square_cm, self.squares[1] * self.square_cm

    def board(self) -> cv2.aruco.CharucoBoard:
        """The OpenCV board (its own frame: origin top-left, y down, cm)."""
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard(self.squares, self.square_cm, self.marker_cm, dictionary)


def charuco_spec(profile: Any) -> CharucoSpec | None:
    """The profile's [charuco] table (None if it has none); CharucoError if it is malformed
    or does not match the profile's size."""
    data = tomllib.loads(Path(profile.path).read_text(encoding="utf-8")).get("charuco")
    if data is None:
        return None
    where = f"{profile.path} [charuco]"
    try:
        spec = CharucoSpec(
            squares=(int(data["squares"][0]), int(data["squares"][1])),
            square_cm=float(data["square_cm"]),
            marker_cm=float(data["marker_cm"]),
            dictionary=str(data["dictionary"]),
            inverted=bool(data.get("inverted", False)),
        )
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise CharucoError(
            f"{where}: needs squares, square_cm, marker_cm, dictionary ({exc})"
        ) from None
    if not hasattr(cv2.aruco, spec.dictionary):
        raise CharucoError(f"{where}: unknown dictionary {spec.dictionary!r}")
    if not 0 < spec.marker_cm < spec.square_cm:
        raise CharucoError(f"{where}: marker_cm must lie between 0 and square_cm")
    w, h = spec.size_cm
    if abs(w - profile.width_cm) > 1e-6 or abs(h - profile.height_cm) > 1e-6:
        raise CharucoError(
            f"{where}: the squares measure {w:g} x {h:g} cm but the profile says "
            f"{profile.width_cm:g} x {profile.height_cm:g}"
        )
    return spec


def board_texture(spec: CharucoSpec, px_per_cm: int = PX_PER_CM) -> np.ndarray:
    """The front-on texture RGB uint8 [H, W, 3] of the squares, as printed (inverted if so)."""
    w, h = spec.size_cm
    # a 1 px white margin: what the call `generateImage(size, 0, 1)` made, whose 0 was the
    # output array, not the margin (the shipped ChArUco models were trained on it)
    size = (round(w * px_per_cm), round(h * px_per_cm))
    grey = spec.board().generateImage(size, marginSize=1)
    if spec.inverted:
        grey = 255 - grey
    return cv2.cvtColor(grey, cv2.COLOR_GRAY2RGB)


class CharucoFinder:
    """ChArUco corners in a photo -> object-plane <-> pixel correspondences (object frame)."""

    def __init__(self, spec: CharucoSpec) -> None:
        self.spec = spec
        board = spec.board()
        params = cv2.aruco.DetectorParameters()
        params.detectInvertedMarker = spec.inverted
        self.detector = cv2.aruco.CharucoDetector(board, cv2.aruco.CharucoParameters(), params)
        w, h = spec.size_cm
        xy = np.asarray(board.getChessboardCorners())[:, :2].astype(np.float64)
        #: Object-frame (x, y) cm of every ChArUco corner id, (M, 2).
        self.object_xy = np.column_stack([xy[:, 0] - w / 2, h / 2 - xy[:, 1]])

    def find(self, rgb: np.ndarray) -> Correspondences | None:
        """Correspondences of the ChArUco corners found in `rgb` (RGB uint8), None if fewer
        than MIN_CORNERS."""
        grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
        corners, ids, _, _ = self.detector.detectBoard(grey)
        if ids is None or len(ids) < MIN_CORNERS:
            return None
        ids = ids.ravel().astype(int)
        uv = corners.reshape(-1, 2).astype(np.float64)
        return Correspondences(object_xy=self.object_xy[ids], image_uv=uv, method="charuco")


def read_camera_array(path: Path) -> dict[int, Camera]:
    """Cameras by id from a caliscope camera_array.toml ([cameras.N]: size, matrix,
    distortions); CharucoError with the reason if the file is not one."""
    try:
        data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
        cameras = {}
        for key, entry in data["cameras"].items():
            K = np.asarray(entry["matrix"], dtype=np.float64).reshape(3, 3)
            dist = np.asarray(entry["distortions"], dtype=np.float64).ravel()
            size = (int(entry["size"][0]), int(entry["size"][1]))
            cameras[int(key)] = Camera(K, dist, size)
    except (OSError, tomllib.TOMLDecodeError, KeyError, TypeError, ValueError) as exc:
        raise CharucoError(f"{path}: not a camera_array.toml with [cameras.N] ({exc})") from None
    return cameras


def extract_frames(video: Path, out: Path, every: int = 1, prefix: str = "") -> list[Path]:
    """Every `every`-th frame of `video` as out/<prefix>frame-NNNN.png (lossless); the paths."""
    cap = cv2.VideoCapture(str(video))
    if not cap.isOpened():
        raise CharucoError(f"cannot read video {video}")
    out.mkdir(parents=True, exist_ok=True)
    written, index = [], 0
    try:
        while True:
            ok, bgr = cap.read()
            if not ok:
                break
            if index % every == 0:
                path = out / f"{prefix}frame-{index:04d}.png"
                cv2.imwrite(str(path), bgr)
                written.append(path)
            index += 1
    finally:
        cap.release()
    if not written:
        raise CharucoError(f"{video}: no frame could be decoded")
    return written


def label_video_source(
    src: Path,
    out: Path,
    profile: Any,
    camera: Camera,
    progress: Callable[[list[Path]], Iterable[Path]] = iter,
) -> dict[str, Any]:
    """Label the staged frames of one camera (`src`: images/, source.json, LICENSE) into the
    corpus folder `out` with the ChArUco detector and `camera`; return the manifest.

    Frames without enough corners, or whose pose reprojects worse than MAX_RMS_PX, are listed
    in failed.txt. Frames without a detection are not taken as class 0: the detector missing
    a board does not show that it is absent.
    """
    spec = charuco_spec(profile)
    if spec is None:
        raise CharucoError(f"profile {profile.name!r} has no [charuco] table")
    finder = CharucoFinder(spec)
    matcher = TextureMatcher(board_texture(spec), profile.width_cm, profile.height_cm)
    meta, paths = prepare_source(src, out)
    corners_xy = object_corners(profile.width_cm, profile.height_cm)
    z_split = float(profile.geometry.z_split_cm)
    rows: list[dict[str, Any]] = []
    overlays, failed, checks = [], [], []
    for path in progress(paths):
        bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if bgr is None:
            failed.append(f"{path.name}: not a readable image")
            continue
        rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
        size = (rgb.shape[1], rgb.shape[0])
        cam = camera.scaled(size)
        corr = finder.find(rgb)
        if corr is None:
            failed.append(f"{path.name}: fewer than {MIN_CORNERS} ChArUco corners")
            continue
        try:
            lab = label_from_points(corr, cam, corners_xy, z_split)
        except ValueError as exc:
            failed.append(f"{path.name}: {exc}")
            continue
        if lab.rms > MAX_RMS_PX:
            failed.append(f"{path.name}: reprojection RMS {lab.rms:.2f} px too large")
            continue
        checks.append(_texture_check(matcher, rgb, cam, corners_xy, z_split, lab))
        row, overlay = store_labelled(rgb, lab, out, path, profile)
        rows.append(row)
        overlays.append(overlay)
    contact_sheet(overlays, out / "overlays.jpg")
    found = [c for c in checks if c is not None]
    manifest = {
        "generator": "planar-pose corpus charuco",
        "kind": "board",
        "source": meta,
        "profile": profile.name,
        "calibration": {
            "K": camera.K.tolist(),
            "dist": camera.dist.tolist(),
            "size": list(camera.size or ()),
        },  # fmt: skip
        "count": len(rows),
        "photos": len(paths),
        "failed": len(failed),
        "failed_by_reason": failure_reasons(failed),
        "texture_check": {
            "found": len(found),
            "class_agrees": sum(c["agree"] for c in found),
            "median_centre_diff_cm": float(np.median([c["diff_cm"] for c in found]))
            if found
            else None,
        },
    }
    return write_source(out, rows, failed, manifest)


def _texture_check(
    matcher: TextureMatcher,
    rgb: np.ndarray,
    camera: Camera,
    corners_xy: np.ndarray,
    z_split: float,
    lab: Any,
) -> dict[str, Any] | None:
    """The texture matcher's pose of the same frame against the detector's: class agreement
    and camera-centre distance (cm); None where feature matching finds no pose."""
    result = matcher.match(rgb)
    if result.H is None or result.inlier_xy is None or result.inlier_uv is None:
        return None
    corr = Correspondences(result.inlier_xy, result.inlier_uv, "texture")
    try:
        theirs = label_from_points(corr, camera, corners_xy, z_split)
    except ValueError:
        return None
    agree = int(pose_class(theirs.centre, z_split)) == lab.label
    return {"agree": agree, "diff_cm": float(np.linalg.norm(theirs.centre - lab.centre))}
