"""The feature-based baseline (SPEC section 9): local features, RANSAC homography, planar PnP.

For each image: SIFT and/or ORB features (OpenCV), matched to the profile's front-on texture
with Lowe's ratio test (`train.real.corners.TextureMatcher`), a RANSAC homography
(`cv2.findHomography`), the four object corners mapped through it, planar PnP with IPPE
(`cv2.solvePnP(..., flags=cv2.SOLVEPNP_IPPE)`), the camera centre c = -R^T t and SPEC section
3's class. No homography (too few matches or inliers, degenerate or mirrored H) means class 0.

Small images are enlarged (cubic) to `min_width` pixels before detection. The ratio-test and
RANSAC thresholds can be tuned on a validation split (`tune`), never on the test split.

Intrinsics per image (`dataset_cameras`): fx, fy, cx, cy (and k1.. if present) columns of the
data set's labels.csv (empty for a corpus photo without the object: the default guess of
`train.real.calibration.default_camera`); else, for a real data set whose source folder holds
a calibration.json, that calibration scaled to the image size (distortion included); else its
focal_scale column (synthetic sets: the SPEC intrinsics for the image size, fx and fy scaled);
else the SPEC ones.
"""

from __future__ import annotations

import csv
import itertools
import json
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy as np

from service.core.frame import object_corners
from service.core.geometry import apply_homography, camera_centre, intrinsics
from service.core.paths import REPO_ROOT
from service.core.regions import pose_class
from train.network.evaluate import compute_metrics
from train.real.calibration import Calibration, Camera, default_camera
from train.real.corners import FEATURES, ImageFeatures, MatchResult, TextureMatcher

FEATURE_CHOICES = (*FEATURES, "both")
#: The validation grid of `tune`: Lowe ratios x RANSAC thresholds (pixels of the image).
RATIO_GRID = (0.7, 0.75, 0.8, 0.85, 0.9)
RANSAC_GRID = (1.0, 2.0, 4.0)


@dataclass(frozen=True)
class BaselineConfig:
    """Baseline settings: features ("sift", "orb" or "both": the one with more inliers wins),
    Lowe ratio, RANSAC threshold (px of the image as given), fewest inliers, and the width
    (px) small images are enlarged to before detection."""

    features: str = "sift"
    ratio: float = 0.8
    ransac_px: float = 2.0
    min_inliers: int = 8
    min_width: int = 320


@dataclass(frozen=True)
class BaselinePrediction:
    """Class 0..8, camera centre (3,) cm or None, why there is no pose ("" if there is one),
    features that won ("" for none) and their RANSAC inliers."""

    label: int
    centre: np.ndarray | None
    reason: str
    features: str
    inliers: int


class FeatureBaseline:
    """The feature baseline for one object: texture RGB uint8 [h, w, 3] covering the rectangle
    `width_cm` x `height_cm`, region split `z_split_cm`."""

    def __init__(
        self,
        texture: np.ndarray,
        width_cm: float,
        height_cm: float,
        z_split_cm: float,
        config: BaselineConfig = BaselineConfig(),
    ) -> None:
        if config.features not in FEATURE_CHOICES:
            raise ValueError(f"features must be one of {', '.join(FEATURE_CHOICES)}")
        self.config, self.z_split = config, z_split_cm
        kinds = FEATURES if config.features == "both" else (config.features,)
        self.matchers = {
            k: TextureMatcher(
                texture, width_cm, height_cm, k, config.ratio, config.ransac_px, config.min_inliers
            )
            for k in kinds
        }
        self.corners3 = object_corners(width_cm, height_cm, z=True)

    def with_thresholds(self, ratio: float, ransac_px: float) -> FeatureBaseline:
        """The same baseline (sharing the texture features) with other thresholds."""
        other = FeatureBaseline.__new__(FeatureBaseline)
        other.__dict__.update(self.__dict__)
        other.config = replace(self.config, ratio=ratio, ransac_px=ransac_px)
        return other

    def features(self, rgb: np.ndarray) -> dict[str, ImageFeatures]:
        """Image features per feature kind of an RGB uint8 [H, W, 3] image."""
        upscale = max(1.0, self.config.min_width / rgb.shape[1])
        return {k: m.image_features(rgb, upscale) for k, m in self.matchers.items()}

    def predict_features(
        self, feats: dict[str, ImageFeatures], camera: Camera
    ) -> BaselinePrediction:
        """Class of an image from its features (see `features`) and its camera."""
        c = self.config
        results: dict[str, MatchResult] = {
            k: m.match_features(feats[k], c.ratio, c.ransac_px) for k, m in self.matchers.items()
        }
        found = {k: r for k, r in results.items() if r.H is not None}
        if not found:
            reasons = "; ".join(f"{k}: {r.reason}" for k, r in results.items())
            return BaselinePrediction(0, None, reasons, "", 0)
        kind, best = max(found.items(), key=lambda kv: kv[1].inliers)
        assert best.H is not None
        corners = apply_homography(best.H, self.corners3[:, :2])
        ok, rvec, tvec = cv2.solvePnP(
            self.corners3, corners, camera.K, camera.dist, flags=cv2.SOLVEPNP_IPPE
        )
        if not ok:
            return BaselinePrediction(0, None, f"{kind}: PnP failed", kind, best.inliers)
        R, _ = cv2.Rodrigues(rvec)
        centre = camera_centre(R, tvec.ravel())
        if not np.all(np.isfinite(centre)) or centre[2] <= 0:
            return BaselinePrediction(0, None, f"{kind}: camera behind the object", kind, 0)
        return BaselinePrediction(
            int(pose_class(centre, self.z_split)), centre, "", kind, best.inliers
        )

    def predict(self, rgb: np.ndarray, camera: Camera) -> BaselinePrediction:
        """Class of one RGB uint8 [H, W, 3] image seen by `camera`."""
        return self.predict_features(self.features(rgb), camera)


def dataset_cameras(folder: Path, files: Sequence[str], size: tuple[int, int]) -> list[Camera]:
    """The camera of each image `files` of the data set `folder` (images of `size` (W, H))."""
    with (folder / "labels.csv").open(newline="") as fh:
        rows = {r["file"]: r for r in csv.DictReader(fh)}
    first = next(iter(rows.values()), {})
    if all(k in first for k in ("fx", "fy", "cx", "cy")):
        cams = []
        for f in files:
            r = rows[f]
            if not r["fx"]:  # a photo without the object (class 0) has no calibration
                cams.append(default_camera(size))
                continue
            K = np.array(
                [
                    [float(r["fx"]), 0, float(r["cx"])],
                    [0, float(r["fy"]), float(r["cy"])],
                    [0, 0, 1],
                ]
            )
            dist = [float(r[k]) for k in ("k1", "k2", "p1", "p2", "k3") if r.get(k)]
            cams.append(Camera(K, np.array(dist) if len(dist) == 5 else np.zeros(5)))
        return cams
    manifest_path = folder / "manifest.json"
    manifest = json.loads(manifest_path.read_text()) if manifest_path.is_file() else {}
    if manifest.get("real") and manifest.get("source"):
        source = Path(manifest["source"])
        if not source.is_absolute():
            source = REPO_ROOT / source
        if (source / "calibration.json").is_file():
            cal = Calibration.load(source / "calibration.json")
            return [cal.for_image(Path(f).name, size) for f in files]
    if "focal_scale" in first:  # empty for class 0 images: no camera was drawn
        scales = [float(rows[f]["focal_scale"] or 1.0) for f in files]
        return [Camera(intrinsics(size, s), np.zeros(5)) for s in scales]
    spec = Camera(intrinsics(size), np.zeros(5), size)
    return [spec] * len(files)


class Peer(Protocol):
    """A classical method: one RGB uint8 [H, W, 3] image seen by a camera -> its prediction."""

    def predict(self, rgb: np.ndarray, camera: Camera) -> BaselinePrediction: ...


def run_baseline(
    baseline: Peer,
    images: np.ndarray | Sequence[np.ndarray],
    cameras: Sequence[Camera],
    progress: Callable[[int], Any] | None = None,
) -> tuple[list[BaselinePrediction], float]:
    """Predict images (each RGB uint8 [H, W, 3]) -> (predictions, wall-clock ms per image,
    all steps), with the feature baseline or any other peer."""
    preds = []
    start = time.perf_counter()
    for image, camera in zip(images, cameras, strict=True):
        preds.append(baseline.predict(image, camera))
        if progress is not None:
            progress(1)
    return preds, 1000.0 * (time.perf_counter() - start) / max(len(images), 1)


def failure_summary(preds: Sequence[BaselinePrediction]) -> dict[str, int]:
    """How often each reason for "no pose" occurred, most frequent first."""
    return dict(Counter(p.reason for p in preds if p.reason).most_common())


def tune(
    baseline: FeatureBaseline,
    images: np.ndarray,
    labels: np.ndarray,
    cameras: Sequence[Camera],
    progress: Callable[[int], Any] | None = None,
) -> tuple[FeatureBaseline, dict[str, Any]]:
    """Pick the ratio and RANSAC threshold of best accuracy on validation images [N, H, W, 3]
    (features computed once per image). Returns the tuned baseline and the grid's accuracies;
    the baseline's own setting is tried first and kept on ties."""
    feats = []
    for image in images:
        feats.append(baseline.features(image))
        if progress is not None:
            progress(1)
    grid = {}
    best, best_acc = baseline, -1.0
    own = (baseline.config.ratio, baseline.config.ransac_px)
    for ratio, ransac in [own, *itertools.product(RATIO_GRID, RANSAC_GRID)]:
        if f"ratio={ratio},ransac_px={ransac}" in grid:
            continue
        candidate = baseline.with_thresholds(ratio, ransac)
        pred = [candidate.predict_features(f, c).label for f, c in zip(feats, cameras, strict=True)]
        acc = float(np.mean(np.asarray(pred) == labels))
        grid[f"ratio={ratio},ransac_px={ransac}"] = acc
        if acc > best_acc:
            best, best_acc = candidate, acc
    return best, {"chosen": asdict(best.config), "val_accuracy": best_acc, "grid": grid}


def evaluate_baseline(
    baseline: FeatureBaseline,
    images: np.ndarray,
    labels: np.ndarray,
    cameras: Sequence[Camera],
    progress: Callable[[int], Any] | None = None,
) -> tuple[dict[str, Any], dict[str, int]]:
    """SPEC 10 metrics (`train.network.evaluate.compute_metrics`) and the failure reasons."""
    preds, ms = run_baseline(baseline, images, cameras, progress)
    metrics = compute_metrics(labels, np.array([p.label for p in preds]), ms)
    return metrics, failure_summary(preds)
