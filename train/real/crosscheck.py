"""An independent second labeller, to check the corpus labels of `train.real.corpus`.

It shares only the photo (as stored) and the camera intrinsics of labels.csv with the first
labeller, and differs in every step that decides the class:

* corners: OpenCV's classic `cv2.findChessboardCorners` + `cornerSubPix` (not the
  sector-based detector);
* pose: `cv2.solvePnP` with IPPE on the distorted points, refined by OpenCV's
  Levenberg-Marquardt (`cv2.solvePnPRefineLM`) to the least reprojection error, as any
  maximum-likelihood pose is (not undistortion + normalised DLT + this project's refinement);
* half turn: the colour of the four corner squares of the 10 x 7 board (the two on the -X
  side are black), sampled outside the inner-corner grid (not the parity of the inner squares).

`crosscheck_folder` returns, per photo, both classes and the camera-centre difference.

The stored photos are downscaled (longer side at most 640 px) while the labels were made at
full resolution. Given `originals` (a folder laid out like the staged sources,
`<originals>/<source>/images/<original>`, the file named by the `original` column of
labels.csv), the check reads each photo's full-resolution original instead, with the stored
intrinsics scaled back to the original's size (`Camera.scaled`). A photo whose original
is missing, or is not of a size the stored photo could have been made from, is read as
stored; the row says which (`read`: "original" or "stored"; `fallback`: why, or None).
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from service.core.regions import boundary_margin_cm, pose_class
from train.real.calibration import Camera
from train.real.corners import ChessboardPattern
from train.real.corpus import stored_size


def _classic_corners(grey: np.ndarray, pattern: ChessboardPattern) -> np.ndarray | None:
    size = (pattern.inner_cols, pattern.inner_rows)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    found, corners = cv2.findChessboardCorners(grey, size, flags=flags)
    if not found:
        return None
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 40, 0.01)
    return cv2.cornerSubPix(grey, corners, (5, 5), (-1, -1), criteria).reshape(-1, 2)


def _corner_square_grey(
    grey: np.ndarray,
    rvec: np.ndarray,
    tvec: np.ndarray,
    K: np.ndarray,
    dist: np.ndarray,
    pattern: ChessboardPattern,
) -> tuple[float, float]:
    """Mean grey of the two corner squares on the -X side and of the two on the +X side."""
    half_w = (pattern.inner_cols + 1) / 2 * pattern.square_cm - pattern.square_cm / 2
    half_h = (pattern.inner_rows + 1) / 2 * pattern.square_cm - pattern.square_cm / 2
    centres = np.array([[-half_w, -half_h, 0], [-half_w, half_h, 0],
                        [half_w, -half_h, 0], [half_w, half_h, 0]])  # fmt: skip
    uv, _ = cv2.projectPoints(centres, rvec, tvec, K, dist)
    blurred = cv2.blur(grey, (3, 3)).astype(np.float32)
    h, w = grey.shape
    vals = [
        float(blurred[int(np.clip(round(v), 0, h - 1)), int(np.clip(round(u), 0, w - 1))])
        for u, v in uv.reshape(-1, 2)
    ]
    return (vals[0] + vals[1]) / 2, (vals[2] + vals[3]) / 2


def independent_centre(
    grey: np.ndarray, K: np.ndarray, dist: np.ndarray, pattern: ChessboardPattern
) -> np.ndarray | None:
    """Camera centre (3,) cm in the object frame, or None when the board is not found."""
    raw = _classic_corners(grey, pattern)
    if raw is None:
        return None
    grid = pattern.grid_xy()
    # A planar grid fits as well mirrored (the board seen from behind): keep the orientations
    # that put the camera in front of it (z > 0), a half turn apart.
    front: list[tuple[np.ndarray, np.ndarray]] = []
    for sx, sy in ((1, 1), (-1, -1), (1, -1), (-1, 1)):
        obj = np.column_stack([grid * [sx, sy], np.zeros(len(grid))])
        ok, rvec, tvec = cv2.solvePnP(obj, raw, K, dist, flags=cv2.SOLVEPNP_IPPE)
        if not ok:
            continue
        rvec, tvec = cv2.solvePnPRefineLM(obj, raw, K, dist, rvec, tvec)
        if (-cv2.Rodrigues(rvec)[0].T @ tvec)[2, 0] > 0:
            front.append((rvec, tvec))
    if not front:
        return None

    def black_on_minus_x(b: tuple[np.ndarray, np.ndarray]) -> float:
        minus, plus = _corner_square_grey(grey, b[0], b[1], K, dist, pattern)
        return plus - minus

    rvec, tvec = max(front, key=black_on_minus_x)
    R, _ = cv2.Rodrigues(rvec)
    return (-R.T @ tvec).ravel()


def original_path(originals: Path, source: str, original: str) -> Path:
    """Where the full-resolution original of a stored photo is: the staged-source layout."""
    return originals / source / "images" / original


def _photo(
    folder: Path, row: dict[str, str], K: np.ndarray, originals: Path | None
) -> tuple[np.ndarray | None, np.ndarray, str, str | None]:
    """(grey image, its K, "original" | "stored", why the original was not used or None).

    An original's K is the stored K scaled back to its size (`Camera.scaled`, the convention
    the corpus scaled the full-resolution labels down with, so that this inverts it)."""

    def stored(why: str | None) -> tuple[np.ndarray | None, np.ndarray, str, str | None]:
        return cv2.imread(str(folder / row["file"]), cv2.IMREAD_GRAYSCALE), K, "stored", why

    if originals is None:
        return stored(None)
    path = original_path(originals, folder.name, row.get("original") or "")
    grey = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE) if path.is_file() else None
    if grey is None:
        return stored("original not found")
    size = (grey.shape[1], grey.shape[0])
    small = (int(row["width"]), int(row["height"]))
    if stored_size(size) != small:
        return stored("original of another size than the stored photo's")
    return grey, Camera(K, np.zeros(5), small).scaled(size).K, "original", None


def crosscheck_folder(
    folder: Path, pattern: ChessboardPattern, z_split: float, originals: Path | None = None
) -> list[dict[str, Any]]:
    """Both labellers on every photo of a labelled corpus folder: one dict per photo.

    Reads the stored photos, or with `originals` the full-resolution originals where found
    (see the module docstring)."""
    with (folder / "labels.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    out: list[dict[str, Any]] = []
    for row in rows:
        K = np.array([[float(row["fx"]), 0, float(row["cx"])],
                      [0, float(row["fy"]), float(row["cy"])], [0, 0, 1]])  # fmt: skip
        dist = np.array([float(row[k] or 0) for k in ("k1", "k2", "p1", "p2", "k3")])
        grey, K, read, fallback = _photo(folder, row, K, originals)
        ours = np.array([float(row[f"cam_{a}"]) for a in "xyz"])
        theirs = None if grey is None else independent_centre(grey, K, dist, pattern)
        out.append(
            {
                "file": row["file"],
                "read": read,
                "fallback": fallback,
                "class": int(row["class"]),
                "independent_class": None if theirs is None else int(pose_class(theirs, z_split)),
                "centre_diff_cm": None if theirs is None else float(np.linalg.norm(ours - theirs)),
                # How far the camera centre is from the nearest region boundary (cm).
                "boundary_cm": float(boundary_margin_cm(ours, z_split)),
            }
        )
    return out
