"""The data-set folder format (SPEC section 7): writing its files, reading it into arrays.

On disk a data set is a folder a person can open:

* `images/...`: the images (any size; resized on load);
* `labels.csv`: one row per image, at least `file` (relative to the folder), `class` (0..8)
  and `split` (train / val / test); `LABEL_COLUMNS` for synthetic sets (camera centre and
  look-at target in cm, object frame; SPEC blur level; roll in degrees; focal-length scale;
  lens distortion k1; the object's four corners in pixels, `CORNER_COLUMNS`);
* `manifest.json`: generator and version, profile, size [W, H], counts.

`train.synth.generate` makes synthetic sets, `train.real` real ones; both write them with
`write_labels` and `write_manifest`, and everything reads them with `load_dataset`.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import os
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from service.core.pose import Camera
from service.core.preprocess import ImageDecodeError, decode_image, resize_rgb
from service.core.regions import NUM_CLASSES, boundary_margin_cm

#: The splits of every data set, in the order they are listed.
SPLITS = ("train", "val", "test")
#: The file names of a data set folder.
LABELS_FILE, MANIFEST_FILE = "labels.csv", "manifest.json"
#: Bumped when the decoded cache format changes.
CACHE_VERSION = "1.0"
CACHE_DIR = ".cache"
#: Image pixels of the object corners (in `CORNER_ORDER`) at the set's size.
CORNER_COLUMNS = [f"corner_{a}{i}" for i in range(4) for a in "xy"]
LABEL_COLUMNS = [
    "file",
    "class",
    "cam_x",
    "cam_y",
    "cam_z",
    "target_x",
    "target_y",
    "target_z",
    "blur",
    "split",
    "roll_deg",
    "focal_scale",
    "k1",
    *CORNER_COLUMNS,
]


#: OpenCV's 5 distortion coefficients as labels.csv names them.
DIST_COLUMNS = ("k1", "k2", "p1", "p2", "k3")


def camera_of_row(row: dict[str, str]) -> Camera | None:
    """A labelled real photo's calibration (its row's fx, fy, cx, cy at width x height, and
    OpenCV's 5 coefficients), or None for a row without one (renders, class-0 photos)."""
    if not row.get("fx") or not row.get("width"):
        return None
    size = (int(float(row["width"])), int(float(row["height"])))
    fx, fy, cx, cy = (float(row[k]) for k in ("fx", "fy", "cx", "cy"))
    return Camera(fx, size, fy, cx, cy, tuple(float(row.get(k) or 0.0) for k in DIST_COLUMNS))


def corners_of_row(row: dict[str, str]) -> np.ndarray | None:
    """A row's labelled corners [4, 2] px (`CORNER_COLUMNS`), or None for a row without."""
    if not row.get("corner_x0"):
        return None
    return np.array([float(row[c]) for c in CORNER_COLUMNS]).reshape(4, 2)


class DatasetError(ValueError):
    """A data set that cannot be made (bad arguments, existing folder) or read."""


@dataclass
class LoadedDataset:
    """A data set (or one split of it) in memory.

    `images` uint8 [N, H, W, 3] RGB, `labels` int64 [N] classes 0..8, `rows` the labels.csv
    rows of these images (all columns as strings), `manifest` the parsed manifest.json.
    """

    path: Path
    images: np.ndarray
    labels: np.ndarray
    rows: list[dict[str, str]]
    manifest: dict[str, Any]

    @property
    def size(self) -> tuple[int, int]:
        """Image size (W, H) in pixels."""
        return int(self.images.shape[2]), int(self.images.shape[1])

    def column(self, name: str) -> list[str]:
        """One labels.csv column of these images."""
        return [row[name] for row in self.rows]

    def pixel_aspect(self) -> np.ndarray:
        """float32 [N]: height over width of each image's pixels in the scene (the
        `pixel_aspect` column of real photos resized to the set's size,
        `service.core.preprocess.NetworkFrame.pixel_aspect`); 1 where the column is absent or
        empty (renders)."""
        return np.array([float(r.get("pixel_aspect") or 1.0) for r in self.rows], np.float32)

    def corners(self) -> np.ndarray:
        """float32 [N, 4, 2]: each image's labelled object corners (px, `CORNER_COLUMNS`); nan
        for rows without them (class 0, photos without corners)."""
        out = np.full((len(self.rows), 4, 2), np.nan, np.float32)
        for i, row in enumerate(self.rows):
            if row.get(CORNER_COLUMNS[0]):
                out[i] = np.array([float(row[c]) for c in CORNER_COLUMNS]).reshape(4, 2)
        return out

    def board_cut(self) -> np.ndarray:
        """float [N]: 1 where the frame cuts the object (a labelled corner lies outside
        [0, W] x [0, H] px), 0 where all four are in it, nan for rows without corners (class 0)."""
        uv = self.corners()
        inside = ((uv >= 0) & (uv <= self.size)).all(axis=(1, 2))
        return np.where(np.isnan(uv).any(axis=(1, 2)), np.nan, (~inside).astype(float))

    def boundary_margin_cm(self) -> np.ndarray:
        """float [N]: how far (cm) each image's camera centre is from the nearest region
        boundary (the planes x = 0, y = 0, z = z_split of the object frame, SPEC section 3);
        nan for class 0 and rows without a camera centre."""
        z_split = float(self.manifest.get("profile", {}).get("z_split_cm", "nan"))
        out = np.full(len(self.rows), np.nan)
        for i, (row, label) in enumerate(zip(self.rows, self.labels, strict=True)):
            try:
                centre = [float(row[f"cam_{a}"]) for a in "xyz"]
            except (KeyError, ValueError):
                continue
            if label > 0:
                out[i] = boundary_margin_cm(centre, z_split)
        return out


def _read_table(path: Path) -> tuple[bytes, list[dict[str, str]]]:
    labels = path / LABELS_FILE
    if not path.is_dir():
        raise DatasetError(f"data set folder not found: {path}")
    if not labels.is_file():
        raise DatasetError(f"not a data set (no labels.csv): {path}")
    raw = labels.read_bytes()
    try:
        rows = list(csv.DictReader(io.StringIO(raw.decode("utf-8"))))
    except (UnicodeDecodeError, csv.Error) as exc:
        raise DatasetError(f"{labels}: not a readable CSV ({exc})") from exc
    if not rows:
        raise DatasetError(f"{labels} has no rows")
    missing = {"file", "class", "split"} - set(rows[0])
    if missing:
        raise DatasetError(f"{labels} lacks column(s) {sorted(missing)}")
    for n, row in enumerate(rows, start=2):
        if row["split"] not in SPLITS:
            raise DatasetError(
                f"{labels} line {n}: split must be train/val/test, got {row['split']!r}"
            )
        if not (row["class"] or "").isdigit() or int(row["class"]) >= NUM_CLASSES:
            raise DatasetError(f"{labels} line {n}: class must be 0..8, got {row['class']!r}")
    return raw, rows


def write_labels(path: Path, rows: list[dict[str, Any]], columns: list[str] | None = None) -> None:
    """Write labels.csv rows (`columns`, default LABEL_COLUMNS) to `path`."""
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(
            fh, fieldnames=columns or LABEL_COLUMNS, lineterminator="\n", extrasaction="ignore"
        )
        writer.writeheader()
        writer.writerows(rows)


def write_manifest(
    folder: Path, fields: dict[str, Any], rows: list[dict[str, Any]] | None = None
) -> dict[str, Any]:
    """Write `folder`/manifest.json from `fields` and return what was written.

    With the labels.csv `rows`, also `count`, the images per class 0..8 (`class_counts`) and,
    where the rows have a split, per split (`counts`), unless `fields` gives them.
    """
    manifest = dict(fields)
    if rows is not None:
        classes = [int(r["class"]) for r in rows]
        manifest.setdefault("count", len(rows))
        if all(r.get("split") in SPLITS for r in rows):
            manifest.setdefault("counts", {s: sum(r["split"] == s for r in rows) for s in SPLITS})
        manifest.setdefault("class_counts", np.bincount(classes, minlength=NUM_CLASSES).tolist())
    (folder / MANIFEST_FILE).write_text(json.dumps(manifest, indent=1) + "\n")
    return manifest


def read_splits(path: Path) -> dict[str, str]:
    """splits.toml of a corpus: {source id: train | val | test} from its [splits] table."""
    if not path.is_file():
        raise FileNotFoundError(f"corpus split file not found: {path}")
    try:
        table = tomllib.loads(path.read_text(encoding="utf-8")).get("splits", {})
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not valid TOML ({exc})") from None
    bad = {k: v for k, v in table.items() if v not in SPLITS}
    if bad:
        raise ValueError(f"{path}: splits must be train, val or test, got {bad}")
    return dict(table)


def corpus_sources(corpus: Path) -> list[Path]:
    """The labelled source folders of a corpus (boards/* and negatives/*), sorted."""
    found = sorted(p.parent for p in corpus.glob("*/*/labels.csv"))
    if not found:
        raise ValueError(f"no labelled source (*/*/labels.csv) in {corpus}")
    return found


def read_manifest(path: Path) -> dict[str, Any]:
    """The parsed manifest.json of the data set folder `path`; DatasetError if absent or bad."""
    file = path / MANIFEST_FILE
    if not file.is_file():
        raise DatasetError(f"not a data set (no manifest.json): {path}")
    try:
        manifest = json.loads(file.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DatasetError(f"{file}: not valid JSON ({exc})") from exc
    if not isinstance(manifest, dict):
        raise DatasetError(f"{file}: expected a JSON object")
    return manifest


def _decode_all(path: Path, rows: list[dict[str, str]], size: tuple[int, int]) -> np.ndarray:
    w, h = size
    images = np.empty((len(rows), h, w, 3), np.uint8)
    for i, row in enumerate(rows):
        file = path / row["file"]
        try:
            images[i] = resize_rgb(decode_image(file.read_bytes()), size)
        except FileNotFoundError:
            raise DatasetError(
                f"{path}: image {row['file']} listed in labels.csv is missing"
            ) from None
        except (OSError, ImageDecodeError) as exc:
            raise DatasetError(f"{path}: cannot read image {row['file']} ({exc})") from exc
    return images


def _cache_key(raw_labels: bytes, size: tuple[int, int]) -> str:
    return hashlib.sha256(raw_labels + f"|{size[0]}x{size[1]}|{CACHE_VERSION}".encode()).hexdigest()


def _cached_images(
    path: Path, raw: bytes, rows: list[dict[str, str]], size: tuple[int, int]
) -> np.ndarray:
    """All images of the set [N, H, W, 3] from `.cache/` or decoded (then cached).

    The cache is keyed by the bytes of labels.csv and the size; a failure to write it (e.g. a
    read-only folder) only costs the next load a decode.
    """
    cache = path / CACHE_DIR
    key = _cache_key(raw, size)
    array, key_file = (
        cache / f"images-{size[0]}x{size[1]}.npy",
        cache / f"images-{size[0]}x{size[1]}.key",
    )
    if array.is_file() and key_file.is_file() and key_file.read_text() == key:
        try:
            images = np.load(array, mmap_mode="r")
            if images.shape == (len(rows), size[1], size[0], 3):
                return images
        except (OSError, ValueError):
            pass
    images = _decode_all(path, rows, size)
    try:
        cache.mkdir(exist_ok=True)
        tmp = array.with_suffix(f".{os.getpid()}.tmp")
        with tmp.open("wb") as fh:
            np.save(fh, images)
        os.replace(tmp, array)
        key_file.write_text(key)
    except OSError:
        pass
    return images


def load_dataset(
    path: Path | str, split: str | None = None, size: tuple[int, int] | None = None
) -> LoadedDataset:
    """Load a data set folder (synthetic or real) -> LoadedDataset.

    `split`: train, val or test (None: every image, in labels.csv order). `size` (W, H):
    resize to it (default: the manifest's size). Images are decoded and resized with
    `service.core.preprocess` (as in serving) and cached in `<path>/.cache/` (an .npy per size,
    invalidated when labels.csv changes). Raises DatasetError for a missing or corrupt set.
    """
    path = Path(path)
    if split is not None and split not in SPLITS:
        raise DatasetError(f"split must be train, val, test or None, got {split!r}")
    raw, rows = _read_table(path)
    manifest = read_manifest(path)
    if size is None:
        try:
            size = (int(manifest["size"][0]), int(manifest["size"][1]))
        except (KeyError, TypeError, ValueError, IndexError):
            raise DatasetError(f"{path / MANIFEST_FILE}: no valid size [W, H]") from None
    images = _cached_images(path, raw, rows, (int(size[0]), int(size[1])))
    if split is None:
        index = np.arange(len(rows))
    else:
        index = np.array([i for i, r in enumerate(rows) if r["split"] == split], dtype=np.int64)
    selected = (
        np.ascontiguousarray(images[index])
        if len(index)
        else np.empty((0, size[1], size[0], 3), np.uint8)
    )
    labels = np.array([int(rows[i]["class"]) for i in index], dtype=np.int64)
    return LoadedDataset(path, selected, labels, [rows[i] for i in index], manifest)
