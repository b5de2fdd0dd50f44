"""The classical methods the network is compared with ("peers"), by name, on data sets.

* `sift`, `orb`, `both`: the feature baseline (`train.compare.baseline`), its ratio-test and
  RANSAC thresholds tuned on the data set's val split; reported as `baseline-<features>`.
* `chessboard`: OpenCV's chessboard detector + PnP (`train.compare.chessboard_peer`), only for
  a profile that is a chessboard (`train.real.label.chessboard_pattern`); no tuning; reported
  as `opencv-chessboard`. On real sets whose stored photographs are on this machine it is
  also run on those (<= 640 px, not enlarged, no blur) for reference.
* `charuco`: OpenCV's ChArUco detector + PnP (`train.compare.charuco_peer`), only for a
  profile with a [charuco] table (`train.real.charuco`); reported as `opencv-charuco`.

Every runner returns (metrics of `train.network.evaluate.compute_metrics`, info) where info
holds `failures` ({reason for class 0: count}) and `tuning` (None, or what `tune` chose).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from tqdm import tqdm

from service.core.dataset import LoadedDataset
from train.compare.baseline import (
    FEATURE_CHOICES,
    BaselineConfig,
    FeatureBaseline,
    dataset_cameras,
    evaluate_baseline,
)
from train.compare.baseline import tune as tune_baseline
from train.compare.charuco_peer import CharucoPeer
from train.compare.chessboard_peer import ChessboardPeer, evaluate_peer
from train.compare.sets import StoredPhotos, load_part, profile_of
from train.real.charuco import charuco_spec
from train.real.label import chessboard_pattern
from train.real.realset import read_rgb

#: The object's own OpenCV detector: the kind -> its reported name.
DETECTORS = {"chessboard": "opencv-chessboard", "charuco": "opencv-charuco"}
PEER_CHOICES = (*FEATURE_CHOICES, *DETECTORS)


def peer_name(kind: str) -> str:
    """The name a peer has in the reports: baseline-sift, ..., opencv-chessboard."""
    return DETECTORS.get(kind, f"baseline-{kind}")


def default_peers(features: str = "sift") -> list[str]:
    """`compare`'s peers when none are given: the object's own detectors (each used on its
    profiles only) and the feature baseline."""
    return [*DETECTORS, features]


def make_baseline(folder: Path, config: BaselineConfig, profile: str | None) -> FeatureBaseline:
    """The feature baseline for a data set's object profile (its manifest, or `profile`)."""
    prof = profile_of(folder, profile)
    z_split = float(prof.geometry.z_split_cm)
    return FeatureBaseline(
        prof.texture_rgb(), float(prof.width_cm), float(prof.height_cm), z_split, config
    )


def make_detector_peer(
    kind: str, folder: Path, profile: str | None, enlarge: float
) -> ChessboardPeer | CharucoPeer | None:
    """The detector peer `kind` (`DETECTORS`) for a data set's profile, or None when the
    profile is not its kind of board."""
    prof = profile_of(folder, profile)
    z_split = float(prof.geometry.z_split_cm)
    if kind == "charuco":
        spec = charuco_spec(prof)
        return None if spec is None else CharucoPeer(spec, z_split, enlarge)
    pattern = chessboard_pattern(prof)
    return None if pattern is None else ChessboardPeer(pattern, z_split, enlarge)


def _bar(total: int, desc: str, verbose: bool) -> tqdm:
    return tqdm(total=total, desc=desc, disable=not verbose)


def _cameras(data: LoadedDataset) -> list[Any]:
    return dataset_cameras(data.path, data.column("file"), data.size)


def run_baseline_on(
    folder: Path,
    config: BaselineConfig,
    split: str,
    tune: bool,
    profile: str | None = None,
    limit: int = 0,
    verbose: bool = False,
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Feature baseline metrics on one split of a data set, thresholds tuned on its val split
    first (when `tune` and the set has a val split). Returns (metrics, {failures, tuning})."""
    baseline = make_baseline(folder, config, profile)
    info: dict[str, Any] = {"tuning": None}
    if tune and split != "val":
        val = load_part(folder, "val", limit)
        if len(val.labels):
            with _bar(len(val.labels), f"tune on {folder.name}/val", verbose) as bar:
                baseline, info["tuning"] = tune_baseline(
                    baseline, val.images, val.labels, _cameras(val), bar.update
                )
    data = load_part(folder, split, limit)
    if not len(data.labels):
        raise ValueError(f"{folder} has no images in split {split!r}")
    with _bar(len(data.labels), f"baseline on {folder.name}", verbose) as bar:
        metrics, info["failures"] = evaluate_baseline(
            baseline, data.images, data.labels, _cameras(data), bar.update
        )
    return metrics, info


def run_detector_on(
    data: LoadedDataset, kind: str = "chessboard", profile: str | None = None, verbose: bool = False
) -> tuple[dict[str, Any], dict[str, Any]] | None:
    """The detector peer `kind` on loaded images (enlarged 4x with their intrinsics), or None
    when the data set's profile is not its kind of board."""
    peer = make_detector_peer(kind, data.path, profile, enlarge=4)
    if peer is None:
        return None
    with _bar(len(data.labels), f"{kind} detector on {data.path.name}", verbose) as bar:
        metrics, failures = evaluate_peer(
            peer, data.images, data.labels, _cameras(data), bar.update, data.boundary_margin_cm()
        )
    return metrics, {"tuning": None, "failures": failures}


def run_reference(
    data: LoadedDataset, photos: StoredPhotos, profile: str | None = None, verbose: bool = False
) -> tuple[dict[str, Any], dict[str, Any]] | None:
    """The chessboard peer on the stored photographs of `data`'s images, as stored (no
    enlargement, no blur), with their own intrinsics; None when the profile is no chessboard."""
    peer = make_detector_peer("chessboard", data.path, profile, enlarge=1)
    if peer is None:
        return None
    images = [read_rgb(p) for p in photos.paths]
    with _bar(len(images), f"chessboard detector on {photos.name}", verbose) as bar:
        metrics, failures = evaluate_peer(peer, images, data.labels, photos.cameras, bar.update)
    return metrics, {"tuning": None, "failures": failures}


def run_peer_on(
    data: LoadedDataset,
    kind: str,
    split: str,
    tune: bool,
    limit: int = 0,
    verbose: bool = False,
) -> tuple[dict[str, Any], dict[str, Any]] | None:
    """Peer `kind` (one of PEER_CHOICES) on the loaded split `data` of a data set; None when
    it does not apply to the set's object (the chessboard detector on another object)."""
    if kind not in PEER_CHOICES:
        raise ValueError(f"peer must be one of {', '.join(PEER_CHOICES)}, got {kind!r}")
    if kind in DETECTORS:
        return run_detector_on(data, kind, verbose=verbose)
    config = BaselineConfig(features=kind)
    return run_baseline_on(data.path, config, split, tune, limit=limit, verbose=verbose)
