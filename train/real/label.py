"""Labelling real photographs (SPEC section 7): corners -> homography -> pose -> class.

For each photograph: the object is found automatically (`train.real.corners`: the chessboard
detector for a chessboard profile, SIFT matching to the profile texture otherwise) or taken
from a CSV of clicked corners; the points are undistorted with the camera's calibration; the
object-plane -> image homography comes from the normalised DLT over all points
(`service.core.geometry.dlt_homography`) and the initial pose from `pose_from_homography` (nearest
rotation); `refine_pose` then minimises the reprojection error of all points in raw pixels,
through the camera's distortion (Levenberg-Marquardt, `cv2.solvePnPRefineLM`), and keeps the
refined pose only when it is not worse and has the same orientation (board normal, in-plane
axes, camera in front): the DLT alone can be pixels off where the refinement is a fraction of
a pixel. The object frame (which corner is (-X, -Y), the half turn) is fixed before and is not
changed. Then the camera centre c = -R^T t (cm, object frame) and the class from `pose_class`
with the profile's z split.

Output folder (the data set layout of SPEC section 7, readable by `load_dataset` and
`planar-pose realset`): images/ (the photographs, copied), labels.csv (data set columns +
image size, intrinsics, distortion, OpenCV rvec/tvec, the four object corners in raw pixels,
method, reprojection RMS of the final pose in raw pixels), manifest.json, failed.txt and
overlays/<stem>.png with the projected outline and axes.
"""

from __future__ import annotations

import csv
import shutil
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from service.core.dataset import CORNER_COLUMNS, LABEL_COLUMNS, write_manifest
from service.core.frame import object_corners
from service.core.geometry import camera_centre, dlt_homography, pose_from_homography, roll_of_pose
from service.core.inputs import focal_scale
from service.core.regions import pose_class
from train.real.calibration import Calibration, Camera, default_camera
from train.real.corners import ChessboardPattern, Correspondences, TextureMatcher, detect_chessboard
from train.real.realset import moment_of, optical_axis_target, split_moments

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".webp", ".tif", ".tiff")
#: Columns of a real labels.csv besides the data set ones (LABEL_COLUMNS, with the corners).
EXTRA_COLUMNS = (
    ["width", "height", "fx", "fy", "cx", "cy", "k2", "p1", "p2", "k3"]
    + [f"rvec{i}" for i in range(3)]
    + [f"tvec{i}" for i in range(3)]
    + ["method", "points", "reproj_rms_px"]
)
#: Chessboard of the shipped "chessboard" profile: 9 x 6 inner corners, 10 x 7 squares.
CHESSBOARD_INNER = (9, 6)


@dataclass(frozen=True)
class Label:
    """The pose found for one photograph.

    R (3, 3), t (3,) cm: object -> camera; `centre` (3,) cm in the object frame; `corners`
    (4, 2) raw pixels of the object corners in `CORNER_ORDER`; `rms` the
    reprojection RMS (raw px, through the distortion) of the points used by the pose, after
    `refine_pose`; `points` how many were used; `dlt_rms` the same RMS of the DLT pose.
    """

    R: np.ndarray
    t: np.ndarray
    centre: np.ndarray
    label: int
    corners: np.ndarray
    camera: Camera
    method: str
    points: int
    rms: float
    dlt_rms: float = float("nan")


class ObjectFinder:
    """Finds a profile's object in photographs: chessboard corners or texture matching."""

    def __init__(self, profile: Any) -> None:
        self.width_cm, self.height_cm = float(profile.width_cm), float(profile.height_cm)
        self.z_split = float(profile.geometry.z_split_cm)
        self.pattern = chessboard_pattern(profile)
        self.matcher: TextureMatcher | None = None
        if self.pattern is None:
            texture = cv2.imread(str(profile.texture), cv2.IMREAD_COLOR)
            if texture is None:
                raise ValueError(f"cannot read the profile texture {profile.texture}")
            self.matcher = TextureMatcher(
                cv2.cvtColor(texture, cv2.COLOR_BGR2RGB), self.width_cm, self.height_cm, "sift"
            )

    def corners_xy(self) -> np.ndarray:
        """Object corners (4, 2) cm, in `CORNER_ORDER`."""
        return object_corners(self.width_cm, self.height_cm)

    def find(self, rgb: np.ndarray, camera: Camera) -> Correspondences | None:
        """Object-plane <-> raw-pixel correspondences in `rgb`, or None when not found."""
        if self.pattern is not None:
            return detect_chessboard(rgb, self.pattern, camera.undistort, camera.K)
        assert self.matcher is not None
        result = self.matcher.match(rgb)
        if result.H is None or result.inlier_xy is None or result.inlier_uv is None:
            return None
        return Correspondences(result.inlier_xy, result.inlier_uv, "sift")


def chessboard_pattern(profile: Any) -> ChessboardPattern | None:
    """The chessboard of a profile, or None for a general textured object.

    A profile may say so itself (a `chessboard` attribute holding a `ChessboardPattern` or
    (cols, rows) inner corners); the shipped "chessboard" profile is the 10 x 7-square board
    of the real photographs: 9 x 6 inner corners, square = width / 10.
    """
    own = getattr(profile, "chessboard", None)
    if isinstance(own, ChessboardPattern):
        return own
    if own is not None:
        cols, rows = own
    elif profile.name == "chessboard":
        cols, rows = CHESSBOARD_INNER
    else:
        return None
    return ChessboardPattern(int(cols), int(rows), float(profile.width_cm) / (int(cols) + 1))


def label_from_points(
    corr: Correspondences, camera: Camera, corners_xy: np.ndarray, z_split: float
) -> Label:
    """Pose and class from correspondences: undistort, normalised DLT, pose from homography,
    then `refine_pose` (reprojection error of all points, with the distortion)."""
    ideal = camera.undistort(corr.image_uv)
    H = dlt_homography(corr.object_xy, ideal)
    R0, t0 = pose_from_homography(H, camera.K)
    if camera_centre(R0, t0)[2] <= 0:
        raise ValueError("the points put the camera behind the object (mirrored corner order?)")
    dlt_rms = reprojection_rms(corr.object_xy, corr.image_uv, R0, t0, camera)
    R, t, rms = refine_pose(corr.object_xy, corr.image_uv, camera, R0, t0, dlt_rms)
    centre = camera_centre(R, t)
    corners = project(np.column_stack([corners_xy, np.zeros(4)]), R, t, camera.K, camera.dist)
    return Label(
        R, t, centre, int(pose_class(centre, z_split)), corners, camera, corr.method,
        len(ideal), rms, dlt_rms,
    )  # fmt: skip


def reprojection_rms(
    object_xy: np.ndarray, image_uv: np.ndarray, R: np.ndarray, t: np.ndarray, camera: Camera
) -> float:
    """RMS distance (raw px) between `image_uv` (N, 2) and the object points `object_xy`
    (N, 2) cm projected through the pose (R, t) and the camera, distortion included."""
    obj3 = np.column_stack([object_xy, np.zeros(len(object_xy))])
    err = project(obj3, R, t, camera.K, camera.dist) - np.asarray(image_uv, np.float64)
    return float(np.sqrt(np.mean(np.sum(err**2, axis=1))))


#: Levenberg-Marquardt stop of `refine_pose`: iterations, step size.
REFINE_CRITERIA = (cv2.TERM_CRITERIA_MAX_ITER + cv2.TERM_CRITERIA_EPS, 100, 1e-10)


def refine_pose(
    object_xy: np.ndarray,
    image_uv: np.ndarray,
    camera: Camera,
    R0: np.ndarray,
    t0: np.ndarray,
    rms0: float | None = None,
) -> tuple[np.ndarray, np.ndarray, float]:
    """The pose (R, t, reprojection RMS raw px) refined from the initial (R0, t0).

    Minimises the reprojection error of all points `object_xy` (N, 2) cm seen at raw pixels
    `image_uv` (N, 2) through the camera's distortion (`cv2.solvePnPRefineLM`). The refined
    pose is kept only when it is finite, keeps the orientation of the initial one (board
    normal and in-plane x axis on the same side, camera in front of the board: the object
    frame, half turn included, stays the one the points were given in) and reprojects no
    worse; otherwise the initial pose is returned with its own RMS (`rms0` when given).
    """
    R0, t0 = np.asarray(R0, np.float64), np.asarray(t0, np.float64).ravel()
    if rms0 is None:
        rms0 = reprojection_rms(object_xy, image_uv, R0, t0, camera)
    obj3 = np.column_stack([object_xy, np.zeros(len(object_xy))]).astype(np.float64)
    uv = np.asarray(image_uv, np.float64).reshape(-1, 1, 2)
    rvec0, _ = cv2.Rodrigues(R0)
    try:
        rvec, tvec = cv2.solvePnPRefineLM(
            obj3, uv, camera.K, camera.dist, rvec0.copy(), t0.reshape(3, 1).copy(),
            REFINE_CRITERIA,
        )  # fmt: skip
    except cv2.error:
        return R0, t0, rms0
    if not (np.all(np.isfinite(rvec)) and np.all(np.isfinite(tvec))):
        return R0, t0, rms0
    R, t = cv2.Rodrigues(rvec)[0], tvec.ravel()
    same_side = R[:, 2] @ R0[:, 2] > 0 and R[:, 0] @ R0[:, 0] > 0
    if not same_side or camera_centre(R, t)[2] <= 0:
        return R0, t0, rms0
    rms = reprojection_rms(object_xy, image_uv, R, t, camera)
    if not np.isfinite(rms) or rms > rms0:
        return R0, t0, rms0
    return R, t, rms


def project(
    X: np.ndarray, R: np.ndarray, t: np.ndarray, K: np.ndarray, dist: np.ndarray | None
) -> np.ndarray:
    """Object points X (N, 3) cm -> raw pixels (N, 2) through the pose and the camera."""
    rvec, _ = cv2.Rodrigues(R)
    uv, _ = cv2.projectPoints(np.asarray(X, np.float64), rvec, np.asarray(t, np.float64), K, dist)
    return uv.reshape(-1, 2)


def draw_overlay(rgb: np.ndarray, label: Label, width_cm: float, height_cm: float) -> np.ndarray:
    """BGR image with the object's outline (yellow, distortion followed), its axes (x red,
    y green, z blue, half the shorter side long), the corner numbers and the class."""
    bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    thick = max(1, round(max(rgb.shape[:2]) / 400))
    w, h = width_cm / 2, height_cm / 2
    s = np.linspace(0, 1, 25)[:, None]
    corners = object_corners(width_cm, height_cm)[[0, 1, 2, 3, 0]]
    edge = np.concatenate([(1 - s) * corners[i] + s * corners[i + 1] for i in range(4)])
    cam = label.camera
    outline = project(
        np.column_stack([edge, np.zeros(len(edge))]), label.R, label.t, cam.K, cam.dist
    )
    cv2.polylines(bgr, [np.round(outline).astype(np.int32)], True, (0, 220, 255), thick)
    a = min(w, h)
    axes = project(
        np.array([[0, 0, 0], [a, 0, 0], [0, a, 0], [0, 0, a]]), label.R, label.t, cam.K, cam.dist
    )
    o = tuple(np.round(axes[0]).astype(int))
    for k, colour in ((1, (0, 0, 255)), (2, (0, 200, 0)), (3, (255, 80, 0))):
        cv2.arrowedLine(bgr, o, tuple(np.round(axes[k]).astype(int)), colour, thick + 1)
    font = cv2.FONT_HERSHEY_SIMPLEX
    scale = max(0.4, max(rgb.shape[:2]) / 1200)
    for i, p in enumerate(label.corners):
        cv2.putText(bgr, str(i), tuple(np.round(p).astype(int)), font, scale, (255, 0, 255), thick)
    c = label.centre
    text = f"class {label.label}  c=({c[0]:.1f}, {c[1]:.1f}, {c[2]:.1f}) cm  {label.method}"
    cv2.putText(bgr, text, (5, int(20 * scale / 0.5)), font, scale, (0, 0, 0), thick + 2)
    cv2.putText(bgr, text, (5, int(20 * scale / 0.5)), font, scale, (255, 255, 255), thick)
    return bgr


def read_corner_csv(path: Path) -> dict[str, np.ndarray]:
    """Clicked corners: file name -> (4, 2) raw pixels, in `CORNER_ORDER`.

    Columns `file, corner_x0, corner_y0, ..., corner_x3, corner_y3` (others are ignored).
    """
    if not path.is_file():
        raise FileNotFoundError(f"corners CSV not found: {path}")
    with path.open(newline="") as fh:
        reader = csv.DictReader(fh)
        missing = [c for c in ["file", *CORNER_COLUMNS] if c not in (reader.fieldnames or [])]
        if missing:
            raise ValueError(f"{path}: missing column(s) {', '.join(missing)}")
        out: dict[str, np.ndarray] = {}
        for line, row in enumerate(reader, start=2):
            try:
                pts = np.array([float(row[c]) for c in CORNER_COLUMNS]).reshape(4, 2)
            except (TypeError, ValueError):
                raise ValueError(f"{path} line {line}: corner values must be numbers") from None
            if not np.all(np.isfinite(pts)):
                raise ValueError(f"{path} line {line}: corner values must be finite")
            if row["file"] in out:
                raise ValueError(f"{path} line {line}: {row['file']} given twice")
            out[row["file"]] = pts
    return out


def list_images(folder: Path) -> list[Path]:
    """The image files directly in `folder`, sorted by name."""
    if not folder.is_dir():
        raise FileNotFoundError(f"image folder not found: {folder}")
    images = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not images:
        raise ValueError(f"no images ({', '.join(IMAGE_SUFFIXES)}) in {folder}")
    return images


def row_of(file: str, lab: Label, size: tuple[int, int], split: str) -> dict[str, Any]:
    rvec, _ = cv2.Rodrigues(lab.R)
    target = optical_axis_target(lab.centre, rvec.ravel())
    K, d = lab.camera.K, np.resize(lab.camera.dist, 5) if lab.camera.dist.size else np.zeros(5)
    row: dict[str, Any] = {"file": file, "class": lab.label, "blur": 0, "split": split}
    row["roll_deg"] = f"{roll_of_pose(lab.R):.2f}"
    # Focal length relative to the SPEC camera's at the same image width.
    row["focal_scale"] = f"{focal_scale(K[0, 0], size[0]):.4f}"
    row |= {f"cam_{a}": f"{v:.4f}" for a, v in zip("xyz", lab.centre, strict=True)}
    row |= {f"target_{a}": f"{v:.4f}" for a, v in zip("xyz", target, strict=True)}
    row |= {"width": size[0], "height": size[1]}
    intr = K[[0, 1, 0, 1], [0, 1, 2, 2]]
    row |= {k: f"{v:.6f}" for k, v in zip(("fx", "fy", "cx", "cy"), intr, strict=True)}
    row |= {k: f"{v:.6g}" for k, v in zip(("k1", "k2", "p1", "p2", "k3"), d, strict=True)}
    row |= {f"rvec{i}": f"{v:.6f}" for i, v in enumerate(rvec.ravel())}
    row |= {f"tvec{i}": f"{v:.4f}" for i, v in enumerate(lab.t)}
    row |= {c: f"{v:.3f}" for c, v in zip(CORNER_COLUMNS, lab.corners.ravel(), strict=True)}
    row |= {"method": lab.method, "points": lab.points, "reproj_rms_px": f"{lab.rms:.4f}"}
    return row


def _label_photo(
    path: Path,
    finder: ObjectFinder,
    calibration: Calibration | None,
    clicked: np.ndarray | None,
) -> tuple[Label, np.ndarray] | str:
    """(label, RGB image) of one photograph, or the reason it cannot be labelled."""
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        return "unreadable image"
    rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    size = (rgb.shape[1], rgb.shape[0])
    try:
        camera = calibration.for_image(path.name, size) if calibration else default_camera(size)
    except ValueError as exc:
        return str(exc)
    if clicked is not None:
        corr: Correspondences | None = Correspondences(finder.corners_xy(), clicked, "clicked")
    else:
        corr = finder.find(rgb, camera)
    if corr is None:
        return "object not found"
    try:
        return label_from_points(corr, camera, finder.corners_xy(), finder.z_split), rgb
    except ValueError as exc:
        return str(exc)


def label_folder(
    images_dir: Path,
    out: Path,
    profile: Any,
    calibration: Calibration | None = None,
    corners: dict[str, np.ndarray] | None = None,
    seed: int = 0,
    progress: Callable[[Iterable[Path]], Iterable[Path]] = iter,
) -> dict[str, Any]:
    """Label every image of `images_dir` into `out`; return the manifest (with a summary).

    Images with clicked `corners` use them (4 points); the others are detected automatically.
    A copy of the profile's texture image (same bytes) is not a photograph and is skipped.
    Failures (unreadable image, object not found, degenerate points) go to failed.txt.
    """
    texture = Path(profile.texture).read_bytes()
    paths = [p for p in list_images(images_dir) if p.read_bytes() != texture]
    if not paths:
        raise ValueError(f"no images in {images_dir} besides the profile texture")
    corners = corners or {}
    unknown = sorted(set(corners) - {p.name for p in paths})
    if unknown:
        raise ValueError(f"the corners CSV names images not in {images_dir}: {unknown[:5]}")
    finder = ObjectFinder(profile)
    out.mkdir(parents=True, exist_ok=True)
    (out / "overlays").mkdir(exist_ok=True)
    (out / "images").mkdir(exist_ok=True)
    labelled: list[tuple[str, Label, tuple[int, int]]] = []
    failed: list[str] = []
    for path in progress(paths):
        result = _label_photo(path, finder, calibration, corners.get(path.name))
        if isinstance(result, str):
            failed.append(f"{path.name}: {result}")
            continue
        lab, rgb = result
        if (out / "images").resolve() != images_dir.resolve():
            shutil.copy2(path, out / "images" / path.name)
        overlay = draw_overlay(rgb, lab, finder.width_cm, finder.height_cm)
        cv2.imwrite(str(out / "overlays" / f"{path.stem}.png"), overlay)
        labelled.append((f"images/{path.name}", lab, (rgb.shape[1], rgb.shape[0])))

    splits = split_moments([moment_of(f) for f, _, _ in labelled], seed)
    rows = [row_of(f, lab, size, splits[moment_of(f)]) for f, lab, size in labelled]
    with (out / "labels.csv").open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=LABEL_COLUMNS + EXTRA_COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    (out / "failed.txt").write_text("".join(f"{line}\n" for line in failed))
    # The data set layout's image size [W, H], when every photograph has the same one.
    sizes = {size for _, _, size in labelled}
    manifest = {
        "generator": "planar-pose label",
        "variant": "real",
        "real": True,
        "source": str(images_dir),
        "profile": profile.manifest_entry() if hasattr(profile, "manifest_entry") else profile.name,
        "intrinsics": calibration.source
        if calibration
        else "default guess (SPEC field of view, centred)",
        "seed": seed,
        "size": list(sizes.pop()) if len(sizes) == 1 else None,
        "blur": 0,
        "failed": len(failed),
        "methods": {m: sum(r["method"] == m for r in rows) for m in {r["method"] for r in rows}},
        "mean_reproj_rms_px": float(np.mean([lab.rms for _, lab, _ in labelled])) if rows else None,
    }
    return write_manifest(out, manifest, rows) | {"failed_files": failed}


def compare_to_truth(out: Path, truth_csv: Path, z_split: float) -> dict[str, Any]:
    """Camera centre error (cm) and class agreement of out/labels.csv against a ground truth
    labels.csv with `file, cam_x, cam_y, cam_z` (matched by file name, folders ignored)."""
    with truth_csv.open(newline="") as fh:
        truth = {Path(r["file"]).name: r for r in csv.DictReader(fh)}
    with (out / "labels.csv").open(newline="") as fh:
        ours = [r for r in csv.DictReader(fh) if Path(r["file"]).name in truth]
    if not ours:
        raise ValueError(f"no labelled image of {out} is in {truth_csv}")
    keys = ("cam_x", "cam_y", "cam_z")
    ct = np.array([[float(truth[Path(r["file"]).name][k]) for k in keys] for r in ours])
    co = np.array([[float(r[k]) for k in keys] for r in ours])
    err = np.linalg.norm(co - ct, axis=1)
    agree = pose_class(co, z_split) == pose_class(ct, z_split)
    return {
        "count": len(ours),
        "centre_error_cm_mean": float(err.mean()),
        "centre_error_cm_max": float(err.max()),
        "class_agreement": float(agree.mean()),
    }
