"""The classical methods the network is compared with ("peers"), by name, on data sets.

* `sift`, `orb`, `both`: the feature baseline (`train.compare.baseline`), its ratio-test and
  RANSAC thresholds tuned on the data set's val split; reported as `baseline-<features>`.
* `chessboard`: OpenCV's chessboard detector + PnP (`train.compare.chessboard_peer`), only for
  a profile that is a chessboard (`train.real.label.chessboard_pattern`); no tuning; reported
  as `opencv-chessboard`. On real sets whose stored photographs are on this machine it is
  also run on those (<= 640 px, not enlarged, no blur) for reference.

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
from train.compare.chessboard_peer import ChessboardPeer, evaluate_peer
from train.compare.sets import StoredPhotos, load_part, profile_of
from train.real.label import chessboard_pattern
from train.real.realset import read_rgb

PEER_CHOICES = (*FEATURE_CHOICES, "chessboard")


def peer_name(kind: str) -> str:
    """The name a peer has in the reports: baseline-sift, ..., opencv-chessboard."""
    return "opencv-chessboard" if kind == "chessboard" else f"baseline-{kind}"


def default_peers(features: str = "sift") -> list[str]:
    """`compare`'s peers when none are given: the chessboard detector (used on chessboard
    profiles only) and the feature baseline."""
    return ["chessboard", features]


def make_baseline(folder: Path, config: BaselineConfig, profile: str | None) -> FeatureBaseline:
    """The feature baseline for a data set's object profile (its manifest, or `profile`)."""
    prof = profile_of(folder, profile)
    z_split = float(prof.geometry.z_split_cm)
    return FeatureBaseline(
        prof.texture_rgb(), float(prof.width_cm), float(prof.height_cm), z_split, config
    )


def make_chessboard_peer(
    folder: Path, profile: str | None, enlarge: float
) -> ChessboardPeer | None:
    """The chessboard peer for a data set's profile, or None when the profile is no chessboard."""
    prof = profile_of(folder, profile)
    pattern = chessboard_pattern(prof)
    if pattern is None:
        return None
    return ChessboardPeer(pattern, float(prof.geometry.z_split_cm), enlarge)


def _bar(total: int, desc: str, verbose: bool) -> tqdm:
    return tqdm(total=total, desc=desc, disable=not verbose)


def _cameras(data: LoadedDataset) -> list:
    return dataset_cameras(data.path, data.column("file"), data.size)


def run_baseline_on(
    folder: Path,
    config: BaselineConfig,
    split: str,
    tune: bool,
    profile: str | None = None,
    limit: int = 0,
    verbose: bool = False,
) -> tuple[dict, dict[str, Any]]:
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


def run_chessboard_on(
    data: LoadedDataset, profile: str | None = None, verbose: bool = False
) -> tuple[dict, dict[str, Any]] | None:
    """The chessboard peer on loaded images (enlarged 4x with their intrinsics), or None when
    the data set's profile is no chessboard."""
    peer = make_chessboard_peer(data.path, profile, enlarge=4)
    if peer is None:
        return None
    with _bar(len(data.labels), f"chessboard detector on {data.path.name}", verbose) as bar:
        metrics, failures = evaluate_peer(
            peer, data.images, data.labels, _cameras(data), bar.update, data.boundary_margin_cm()
        )
    return metrics, {"tuning": None, "failures": failures}


def run_reference(
    data: LoadedDataset, photos: StoredPhotos, profile: str | None = None, verbose: bool = False
) -> tuple[dict, dict[str, Any]] | None:
    """The chessboard peer on the stored photographs of `data`'s images, as stored (no
    enlargement, no blur), with their own intrinsics; None when the profile is no chessboard."""
    peer = make_chessboard_peer(data.path, profile, enlarge=1)
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
) -> tuple[dict, dict[str, Any]] | None:
    """Peer `kind` (one of PEER_CHOICES) on the loaded split `data` of a data set; None when
    it does not apply to the set's object (the chessboard detector on another object)."""
    if kind not in PEER_CHOICES:
        raise ValueError(f"peer must be one of {', '.join(PEER_CHOICES)}, got {kind!r}")
    if kind == "chessboard":
        return run_chessboard_on(data, verbose=verbose)
    config = BaselineConfig(features=kind)
    return run_baseline_on(data.path, config, split, tune, limit=limit, verbose=verbose)
