"""What the comparison reads: data set splits, their manifests and profiles, model cards, and
the full-size photographs behind real data sets.

Splits are `service.core.dataset.LoadedDataset`s (images RGB uint8 [N, H, W, 3], labels int64 [N],
labels.csv rows); `load_part` only cuts them to the first `limit` images.
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from service.core.dataset import LoadedDataset, load_dataset
from service.core.paths import REPO_ROOT
from service.core.profile import load_profile
from service.core.regions import pose_class
from train.real.calibration import Calibration, Camera, default_camera
from train.real.realset import moment_of, split_moments

#: Where a corpus data set's stored photos live, below the corpus folder: <kind>/<source>/.
CORPUS_KINDS = ("boards", "negatives")


def load_part(folder: Path, split: str, limit: int = 0) -> LoadedDataset:
    """One split ("all" for every image) of a data set, the first `limit` images if limit > 0
    (the data set's own order)."""
    data = load_dataset(folder, split=None if split == "all" else split)
    if limit <= 0 or limit >= len(data.labels):
        return data
    return replace(
        data, images=data.images[:limit], labels=data.labels[:limit], rows=data.rows[:limit]
    )


def manifest_of(folder: Path) -> dict[str, Any]:
    """The data set's manifest.json ({} if it has none)."""
    path = folder / "manifest.json"
    return json.loads(path.read_text()) if path.is_file() else {}


def describe(folder: Path, images: np.ndarray) -> dict[str, Any]:
    """Object, kind ("real (<source folder>)" / C / noC), size (W, H) and blur of a data set,
    from its manifest."""
    m = manifest_of(folder)
    kind = "real" if m.get("real") else str(m.get("variant", "synthetic"))
    if m.get("real") and m.get("source"):  # real sets of different sources stay apart
        kind += f" ({Path(str(m['source'])).name})"
    profile = m.get("profile")
    return {
        "object": str(profile.get("name", "?") if isinstance(profile, dict) else profile),
        "kind": kind,
        "size": (int(images.shape[2]), int(images.shape[1])),
        "blur": m.get("blur", "?"),
        "real": bool(m.get("real")),
    }


def profile_of(folder: Path, override: str | None) -> Any:
    """The object profile of a data set (its manifest's, or `override`, a name or folder)."""
    if override:
        return load_profile(override)
    entry = manifest_of(folder).get("profile")
    name = entry.get("name") if isinstance(entry, dict) else entry
    try:
        return load_profile(name or "chessboard")
    except ValueError:
        # A profile kept outside train/assets/profiles: its folder holds the recorded texture.
        texture = entry.get("texture") if isinstance(entry, dict) else None
        if not texture:
            raise
        path = Path(texture)
        return load_profile((path if path.is_absolute() else REPO_ROOT / path).parent)


def same_object(card: dict[str, Any], folder: Path) -> bool:
    """False when the model card and the data set name different objects: profiles of other
    names, unless they share the texture and the size (the same object seen by another
    camera, as `chessboard-spec` or `book-spec`)."""
    model_profile = card.get("profile", {})
    data_profile = manifest_of(folder).get("profile", {})
    if not isinstance(model_profile, dict) or not isinstance(data_profile, dict):
        return True
    a, b = model_profile.get("name"), data_profile.get("name")
    if a is None or b is None or a == b:
        return True
    keys = ("texture", "width_cm", "height_cm")
    return all(model_profile.get(k) is not None for k in keys) and all(
        model_profile.get(k) == data_profile.get(k) for k in keys
    )


def finetuned_on_real(card: dict[str, Any]) -> bool | None:
    """Whether a model card lists real photographs among its training data (None: unknown)."""
    data = card.get("training", {}).get("data")
    if not isinstance(data, list):
        return None
    return any(isinstance(d, dict) and d.get("real") for d in data)


def photo_set(folder: Path, z_split: float) -> tuple[list[bytes], np.ndarray, list[str]]:
    """Full-size photographs of a labelled folder (labels.csv with file and class or camera
    centre) -> (encoded bytes as stored, classes [N], split of each photo).

    The split is the one `planar-pose realset` gives with its default seed (0): by stereo
    moment, so it matches the real data sets built from the same folder.
    """
    with (folder / "labels.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    data, labels = [], []
    for row in rows:
        data.append((folder / row["file"]).read_bytes())
        if row.get("class", "") != "":
            labels.append(int(row["class"]))
        else:
            centre = [float(row[k]) for k in ("cam_x", "cam_y", "cam_z")]
            labels.append(int(pose_class(np.array(centre), z_split)))
    splits = split_moments([moment_of(r["file"]) for r in rows], seed=0)
    return data, np.array(labels, np.int64), [splits[moment_of(r["file"])] for r in rows]


def encode_png(images: np.ndarray) -> list[bytes]:
    """RGB uint8 images [N, H, W, 3] -> PNG bytes (lossless), as a client would send them."""
    out = []
    for rgb in images:
        ok, buf = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        if not ok:
            raise ValueError("PNG encoding failed")
        out.append(buf.tobytes())
    return out


@dataclass(frozen=True)
class StoredPhotos:
    """The stored photographs behind some images of a real data set: `paths` (files, <= 640 px
    for a corpus), `cameras` (intrinsics at each photo's own size) and what they are (`name`)."""

    name: str
    paths: list[Path]
    cameras: list[Camera]


def _source_folder(manifest: dict[str, Any]) -> Path | None:
    source = manifest.get("source")
    if not source:
        return None
    path = Path(source)
    return path if path.is_absolute() else REPO_ROOT / path


def _camera_of_row(row: dict[str, str], path: Path) -> Camera:
    """Intrinsics of a stored photo from its labels.csv row (fx.. at width x height), or the
    documented default guess for a photo without them (class-0 photos)."""
    if row.get("fx") and row.get("width"):
        K = np.array(
            [
                [float(row["fx"]), 0, float(row["cx"])],
                [0, float(row["fy"]), float(row["cy"])],
                [0, 0, 1],
            ]
        )
        dist = [float(row[k]) for k in ("k1", "k2", "p1", "p2", "k3") if row.get(k)]
        size = (int(float(row["width"])), int(float(row["height"])))
        return Camera(K, np.array(dist) if len(dist) == 5 else np.zeros(5), size)
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ValueError(f"cannot read image {path}")
    return default_camera((image.shape[1], image.shape[0]))


def _read_rows(labels: Path) -> dict[str, dict[str, str]]:
    with labels.open(newline="") as fh:
        return {Path(r["file"]).stem: r for r in csv.DictReader(fh)}


def _corpus_photos(corpus: Path, rows: list[dict[str, str]]) -> StoredPhotos | None:
    """Stored photos of a corpus data set's rows (columns `source` and `original`)."""
    paths, cameras, cache = [], [], {}
    for row in rows:
        stem = Path(row.get("original") or Path(row["file"]).stem.split("__", 1)[-1]).stem
        found = None
        for kind in CORPUS_KINDS:
            folder = corpus / kind / row["source"]
            if (folder / "images" / f"{stem}.jpg").is_file():
                found = folder
                break
        if found is None:
            return None
        if found not in cache:
            cache[found] = (
                _read_rows(found / "labels.csv") if (found / "labels.csv").is_file() else {}
            )
        path = found / "images" / f"{stem}.jpg"
        paths.append(path)
        cameras.append(_camera_of_row(cache[found].get(stem, {}), path))
    return StoredPhotos(f"corpus photos ({corpus.name})", paths, cameras)


def _labelled_folder_photos(source: Path, rows: list[dict[str, str]]) -> StoredPhotos | None:
    """Stored photos of a data set built from one labelled folder (`planar-pose realset`)."""
    by_stem = _read_rows(source / "labels.csv")
    calibration = (
        Calibration.load(source / "calibration.json")
        if (source / "calibration.json").is_file()
        else None
    )
    paths, cameras = [], []
    for row in rows:
        src = by_stem.get(Path(row["file"]).stem)
        if src is None or not (source / src["file"]).is_file():
            return None
        path = source / src["file"]
        cam = _camera_of_row(src, path)
        if calibration is not None:
            cam = calibration.for_image(Path(src["file"]).name, cam.size or (0, 0))
        paths.append(path)
        cameras.append(cam)
    return StoredPhotos(f"{source.name} photos", paths, cameras)


def stored_photos(data: LoadedDataset) -> StoredPhotos | None:
    """The stored photographs of a real data set's images, or None when they are not all
    available (a synthetic set, a corpus not on this machine, a photo missing).

    Corpus sets (labels.csv columns `source` and `original`): the corpus of the manifest's
    `source`, <corpus>/boards|negatives/<source>/images/<stem>.jpg, with the intrinsics of its
    labels.csv (at the stored size). Sets of one labelled folder (`planar-pose realset`):
    that folder's photos, its calibration.json when there is one.
    """
    if not data.manifest.get("real") or not data.rows:
        return None
    folder = _source_folder(data.manifest)
    if folder is None or not folder.is_dir():
        return None
    if "source" in data.rows[0]:
        return _corpus_photos(folder, data.rows)
    if (folder / "labels.csv").is_file():
        return _labelled_folder_photos(folder, data.rows)
    return None
