"""A corpus of real photographs, one source (one camera in one repository) at a time.

A *staged source* is what a person brings in from a public repository (see
train/assets/real/corpus/README.md): `images/` (the photographs as published, full
resolution), `LICENSE` (the repository's licence, verbatim) and `source.json` (repository,
commit, folder, licence, camera, square size if documented).

`label_source` turns a staged board source into a labelled folder of the corpus:

1. the chessboard's inner corners are found at full resolution (`corners.find_grid`);
2. the camera is calibrated from the source's own views (`cv2.calibrateCamera` over all views
   of one image size, k1 k2 p1 p2 with k3 fixed) when there are at least `MIN_CALIBRATION_VIEWS`;
   otherwise only the focal length (and radial k1 from `MIN_K1_VIEWS` views) is fitted to the
   views (principal point at the centre, square pixels);
3. per photo: the colour-parity orientation (`corners.orient_grid`), undistortion, DLT pose
   refined on the reprojection error of all corners through the lens distortion
   (`label.refine_pose`), camera centre, class by the profile's regions; a photo where the
   checker pattern goes on outside the 10 x 7 squares (a 9 x 6 grid found inside a bigger
   board) is dropped. A board of another square size is labelled as if its squares had the
   profile's size: the label follows the apparent size, which is what the network sees.
   Photos whose parity confidence is below `MIN_PARITY` or whose reprojection error is too
   large (`MAX_RMS_FRACTION`, tested on the DLT pose) are dropped and listed in failed.txt
   with the reason;
4. the photo is stored with its longer side at most `STORE_MAX_SIDE` px (JPEG, quality 90);
   intrinsics and corners in labels.csv are for the stored size.

`import_negatives` stores a staged source of photos without the object (class 0), refusing
any photo in which the chessboard detector finds a board.

Output folder: images/, labels.csv, manifest.json (source.json + calibration + counts),
failed.txt, LICENSE and overlays.jpg (a contact sheet of the labelled photos with the board's
outline, axes and class drawn, to check by eye).
"""

from __future__ import annotations

import json
import shutil
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from service.core.dataset import LABEL_COLUMNS, LABELS_FILE, write_labels, write_manifest
from service.core.frame import object_corners
from train.real.calibration import Camera
from train.real.corners import ChessboardPattern, Correspondences, find_grid, orient_grid, to_grey
from train.real.label import (
    EXTRA_COLUMNS,
    Label,
    chessboard_pattern,
    draw_overlay,
    label_from_points,
    list_images,
    project,
    row_of,
)

STORE_MAX_SIDE = 640
JPEG_QUALITY = 90
MIN_CALIBRATION_VIEWS = 8
#: Fewer views: the focal length, and with at least this many views also k1, are fitted.
MIN_K1_VIEWS = 3
#: Below this parity confidence the half turn of the board is a guess: the photo is dropped.
MIN_PARITY = 0.35
#: Largest per-photo reprojection RMS kept, as a fraction of the photo's longer side. It is
#: tested on the DLT pose (before `refine_pose`): stricter than on the refined pose, it keeps
#: out the photos it dropped before the refinement was added (their corners fit badly).
MAX_RMS_FRACTION = 0.004
#: Longer side (px) at which photos without the object are searched for a board.
NEGATIVE_CHECK_SIDE = 800
CORPUS_COLUMNS = LABEL_COLUMNS + EXTRA_COLUMNS + ["parity_confidence", "original"]
SOURCE_KEYS = ("repo", "commit", "folder", "licence")


@dataclass(frozen=True)
class View:
    """One photo with its detected inner corners `raw` (N, 2) px at full resolution."""

    path: Path
    rgb: np.ndarray
    raw: np.ndarray

    @property
    def size(self) -> tuple[int, int]:
        return int(self.rgb.shape[1]), int(self.rgb.shape[0])


def read_source(folder: Path) -> dict[str, Any]:
    """source.json of a staged source, checked: the keys of `SOURCE_KEYS`, a LICENSE file."""
    meta = folder / "source.json"
    if not meta.is_file():
        raise FileNotFoundError(f"not a staged source (no source.json): {folder}")
    try:
        doc = json.loads(meta.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{meta}: not valid JSON ({exc})") from None
    if not isinstance(doc, dict):
        raise ValueError(f"{meta}: expected a JSON object")
    # "folder" may be "" (the repository root); the others must be given.
    missing = [k for k in SOURCE_KEYS if not doc.get(k) and not (k == "folder" and k in doc)]
    if missing:
        raise ValueError(f"{meta}: missing {', '.join(missing)}")
    if not (folder / "LICENSE").is_file():
        raise FileNotFoundError(f"{folder}: no LICENSE file (the repository's licence text)")
    return doc


def read_rgb(path: Path) -> np.ndarray | None:
    """Image file -> RGB uint8 [H, W, 3] (EXIF orientation applied), or None if unreadable."""
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    return None if bgr is None else cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def detect_views(
    paths: Iterable[Path], pattern: ChessboardPattern, failed: list[str]
) -> list[View]:
    """The photos in which the board is found; the others are appended to `failed`."""
    views = []
    for path in paths:
        rgb = read_rgb(path)
        if rgb is None:
            failed.append(f"{path.name}: unreadable image")
            continue
        raw = find_grid(to_grey(rgb), pattern)
        if raw is None:
            failed.append(f"{path.name}: chessboard not found")
            continue
        views.append(View(path, rgb, raw))
    return views


def calibrate(views: list[View], pattern: ChessboardPattern) -> tuple[Camera, float, str]:
    """Intrinsics of the camera that took `views` (all of one size): (camera, RMS px, method).

    With `MIN_CALIBRATION_VIEWS` or more views: full calibration (fx, fy, principal point,
    k1 k2 p1 p2). Fewer: one focal length (and k1 from `MIN_K1_VIEWS` views) with the
    principal point at the image centre.
    """
    size = views[0].size
    grid = np.column_stack([pattern.grid_xy(), np.zeros(len(pattern.grid_xy()))])
    obj = [grid.astype(np.float32)] * len(views)
    img = [v.raw.astype(np.float32).reshape(-1, 1, 2) for v in views]
    K0 = np.array([[max(size), 0, (size[0] - 1) / 2], [0, max(size), (size[1] - 1) / 2], [0, 0, 1]])
    if len(views) >= MIN_CALIBRATION_VIEWS:
        flags, method = cv2.CALIB_FIX_K3, f"calibrateCamera over {len(views)} views"
    else:
        flags = (
            cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_PRINCIPAL_POINT
            | cv2.CALIB_FIX_ASPECT_RATIO | cv2.CALIB_ZERO_TANGENT_DIST
            | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3
        )  # fmt: skip
        method = f"focal length from {len(views)} homographies, principal point at the centre"
        if len(views) < MIN_K1_VIEWS:
            flags |= cv2.CALIB_FIX_K1
        else:
            method += ", k1"
    rms, K, dist, _, _ = cv2.calibrateCamera(obj, img, size, K0.copy(), None, flags=flags)
    return Camera(K, np.asarray(dist, np.float64).ravel()[:5], size), float(rms), method


def _ring_contrast(grey: np.ndarray, label: Label, pattern: ChessboardPattern, ring: int) -> float:
    """Mean grey of the squares expected white minus those expected black, over the ring of
    squares `ring` squares outside the board's outermost ones (0: the outermost squares
    themselves), as if the checker pattern went on. Squares outside the image are skipped;
    NaN when fewer than 4 are visible."""
    cols, rows = pattern.inner_cols + 1, pattern.inner_rows + 1  # squares
    idx = [(i, j) for i in range(-ring, cols + ring) for j in range(-ring, rows + ring)
           if i in (-ring, cols - 1 + ring) or j in (-ring, rows - 1 + ring)]  # fmt: skip
    s = pattern.square_cm
    xy = np.array([[(i + 0.5) * s - cols * s / 2, (j + 0.5) * s - rows * s / 2] for i, j in idx])
    uv = project(np.column_stack([xy, np.zeros(len(xy))]), label.R, label.t,
                 label.camera.K, label.camera.dist)  # fmt: skip
    h, w = grey.shape
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] < h - 1)
    if inside.sum() < 4:
        return float("nan")
    g = cv2.blur(grey, (3, 3)).astype(np.float32)
    vals = g[np.round(uv[inside, 1]).astype(int), np.round(uv[inside, 0]).astype(int)]
    black = np.array([(i + j) % 2 == 0 for i, j in idx])[inside]
    if black.all() or not black.any():
        return float("nan")
    return float(vals[~black].mean() - vals[black].mean())


def pattern_continues(grey: np.ndarray, label: Label, pattern: ChessboardPattern) -> bool:
    """True when the checker pattern goes on outside the labelled board (the detected 9 x 6
    grid is part of a bigger board, whose orientation and size would be wrong): the ring of
    squares just outside has more than half the colour contrast of the board's own edge."""
    edge = _ring_contrast(grey, label, pattern, 0)
    outside = _ring_contrast(grey, label, pattern, 1)
    return bool(np.isfinite(edge) and np.isfinite(outside) and outside > 0.5 * edge)


def scale_label(label: Label, scale: float, size: tuple[int, int]) -> Label:
    """The same pose seen in the photo resized by `scale` (pixel centres kept): K, corners."""
    corners = (label.corners + 0.5) * scale - 0.5
    return replace(label, camera=label.camera.scaled(size), corners=corners)


def stored_size(size: tuple[int, int]) -> tuple[int, int]:
    """The size (W, H) a photo of `size` is stored at: longer side at most STORE_MAX_SIDE,
    sides rounded."""
    scale = min(1.0, STORE_MAX_SIDE / max(size))
    return (round(size[0] * scale), round(size[1] * scale)) if scale < 1.0 else (size[0], size[1])


def store_image(rgb: np.ndarray, path: Path) -> tuple[np.ndarray, float]:
    """Write `rgb` with its longer side at most STORE_MAX_SIDE (JPEG); (stored RGB, scale)."""
    wh = stored_size((rgb.shape[1], rgb.shape[0]))
    small, scale = rgb, 1.0
    if wh != (rgb.shape[1], rgb.shape[0]):
        small = cv2.resize(rgb, wh, interpolation=cv2.INTER_AREA)
        scale = wh[0] / rgb.shape[1]
    bgr = cv2.cvtColor(small, cv2.COLOR_RGB2BGR)
    cv2.imwrite(str(path), bgr, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    return small, scale


def contact_sheet(images: list[np.ndarray], path: Path, cols: int = 6, width: int = 200) -> None:
    """Thumbnails (BGR) `width` px wide in a grid of `cols` columns -> one JPEG at `path`."""
    if not images:
        return
    thumbs = [cv2.resize(im, (width, round(im.shape[0] * width / im.shape[1]))) for im in images]
    h = max(t.shape[0] for t in thumbs)
    rows = -(-len(thumbs) // cols)
    sheet = np.full((rows * h, cols * width, 3), 255, np.uint8)
    for k, t in enumerate(thumbs):
        r, c = divmod(k, cols)
        sheet[r * h : r * h + t.shape[0], c * width : (c + 1) * width] = t
    cv2.imwrite(str(path), sheet, [cv2.IMWRITE_JPEG_QUALITY, 80])


def store_labelled(
    rgb: np.ndarray, lab: Label, out: Path, original: Path, profile: Any
) -> tuple[dict[str, Any], np.ndarray]:
    """Store a labelled photo RGB uint8 [H, W, 3] of the file `original` as
    out/images/<stem>.jpg (`store_image`) -> (its labels.csv row, with the label scaled to
    the stored size; its overlay, BGR)."""
    name = f"images/{original.stem}.jpg"
    small, scale = store_image(rgb, out / name)
    size = (small.shape[1], small.shape[0])
    stored = scale_label(lab, scale, size)
    row = row_of(name, stored, size, "")
    row |= {"original": original.name, "reproj_rms_px": f"{lab.rms * scale:.4f}"}
    return row, draw_overlay(small, stored, profile.width_cm, profile.height_cm)


def failure_reasons(failed: list[str]) -> dict[str, int]:
    """failed.txt lines "<file>: <reason> (<details>)" -> {reason: count}."""
    return dict(Counter(line.split(": ", 1)[1].split(" (")[0] for line in failed))


def prepare_source(src: Path, out: Path) -> tuple[dict[str, Any], list[Path]]:
    meta = read_source(src)
    paths = list_images(src / "images")
    if out.exists():
        shutil.rmtree(out)
    (out / "images").mkdir(parents=True)
    shutil.copy2(src / "LICENSE", out / "LICENSE")
    return meta, paths


def write_source(
    out: Path, rows: list[dict[str, Any]], failed: list[str], manifest: dict[str, Any]
) -> dict[str, Any]:
    """labels.csv, failed.txt and manifest.json of a labelled source; the manifest written."""
    write_labels(out / LABELS_FILE, rows, CORPUS_COLUMNS)
    (out / "failed.txt").write_text("".join(f"{line}\n" for line in failed))
    return write_manifest(out, manifest, rows)


def label_source(
    src: Path,
    out: Path,
    profile: Any,
    progress: Callable[[list[Path]], Iterable[Path]] = iter,
) -> dict[str, Any]:
    """Label the staged board source `src` into the corpus folder `out`; return the manifest."""
    pattern = chessboard_pattern(profile)
    if pattern is None:
        raise ValueError(f"profile {profile.name!r} is not a chessboard: label it with corners")
    meta, paths = prepare_source(src, out)
    failed: list[str] = []
    views = detect_views(progress(paths), pattern, failed)
    by_size: dict[tuple[int, int], list[View]] = {}
    for v in views:
        by_size.setdefault(v.size, []).append(v)
    corners_xy = object_corners(profile.width_cm, profile.height_cm)
    z_split = float(profile.geometry.z_split_cm)
    rows: list[dict[str, Any]] = []
    overlays, calibrations = [], []
    for size, group in sorted(by_size.items()):
        camera, cal_rms, method = calibrate(group, pattern)
        calibrations.append(
            {"size": list(size), "views": len(group), "method": method, "rms_px": cal_rms,
             "K": camera.K.tolist(), "dist_k1k2p1p2k3": camera.dist.tolist()}
        )  # fmt: skip
        for v in group:
            grey = to_grey(v.rgb)
            object_xy, parity = orient_grid(grey, v.raw, pattern, camera.undistort, camera.K)
            if parity < MIN_PARITY:
                failed.append(f"{v.path.name}: orientation unsure (parity confidence {parity:.2f})")
                continue
            corr = Correspondences(object_xy, v.raw, "chessboard")
            try:
                lab = label_from_points(corr, camera, corners_xy, z_split)
            except ValueError as exc:
                failed.append(f"{v.path.name}: {exc}")
                continue
            if lab.dlt_rms > MAX_RMS_FRACTION * max(size):
                failed.append(
                    f"{v.path.name}: reprojection RMS {lab.dlt_rms:.2f} px too large (DLT pose; "
                    f"refined {lab.rms:.2f} px)"
                )
                continue
            if pattern_continues(grey, lab, pattern):
                failed.append(f"{v.path.name}: the checker pattern goes on outside the board")
                continue
            row, overlay = store_labelled(v.rgb, lab, out, v.path, profile)
            rows.append(row | {"parity_confidence": f"{parity:.3f}"})
            overlays.append(overlay)
    contact_sheet(overlays, out / "overlays.jpg")
    manifest = {
        "generator": "planar-pose label (corpus source)",
        "kind": "board",
        "source": meta,
        "profile": profile.name,
        "calibration": calibrations,
        "count": len(rows),
        "photos": len(paths),
        "failed": len(failed),
        "failed_by_reason": failure_reasons(failed),
    }
    return write_source(out, rows, failed, manifest)


def import_negatives(
    src: Path,
    out: Path,
    profile: Any,
    progress: Callable[[list[Path]], Iterable[Path]] = iter,
) -> dict[str, Any]:
    """Store the staged class-0 source `src` (photos without the object) into `out`."""
    pattern = chessboard_pattern(profile)
    meta, paths = prepare_source(src, out)
    failed: list[str] = []
    rows: list[dict[str, Any]] = []
    thumbs = []
    for path in progress(paths):
        rgb = read_rgb(path)
        if rgb is None:
            failed.append(f"{path.name}: unreadable image")
            continue
        if (
            pattern is not None
            and find_grid(to_grey(rgb), pattern, NEGATIVE_CHECK_SIDE) is not None
        ):
            failed.append(f"{path.name}: a chessboard is found in it")
            continue
        name = f"images/{path.stem}.jpg"
        small, _ = store_image(rgb, out / name)
        rows.append({"file": name, "class": 0, "blur": 0, "split": "", "original": path.name,
                     "width": small.shape[1], "height": small.shape[0]})  # fmt: skip
        thumbs.append(cv2.cvtColor(small, cv2.COLOR_RGB2BGR))
    contact_sheet(thumbs, out / "overlays.jpg")
    manifest = {
        "generator": "planar-pose label (corpus source)",
        "kind": "negative",
        "source": meta,
        "profile": profile.name,
        "count": len(rows),
        "photos": len(paths),
        "failed": len(failed),
        "class_counts": [len(rows)] + [0] * 8,
    }
    return write_source(out, rows, failed, manifest)
