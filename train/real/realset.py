"""Real photographs with known camera centres -> a data set on disk (SPEC section 7).

The source folder has images and a labels.csv with at least `file, cam_x, cam_y, cam_z` (the
camera centre in the object frame, cm) and, optionally, OpenCV `rvec0..2` (object -> camera
rotation) used to find where the optical axis meets the object plane (the "target").
Each image is read, turned to RGB, resized to the network size with the service's area
resize, blurred with a SPEC level (`service.core.blur`) and saved as PNG; its class comes from
`service.core.regions.pose_class` with the profile's z split.

Stereo pairs (`leftNN` / `rightNN`) are taken at the same moment: the train / val / test split
(60 / 20 / 20 %, seeded) is drawn over moments, never separating a pair.
"""

from __future__ import annotations

import csv
import re
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from service.core.blur import blur_image
from service.core.dataset import (
    CORNER_COLUMNS,
    LABEL_COLUMNS,
    LABELS_FILE,
    SPLITS,
    corpus_sources,
    read_splits,
    write_labels,
    write_manifest,
)
from service.core.geometry import roll_of_pose
from service.core.inputs import SIZES, focal_scale
from service.core.paths import repo_relative
from service.core.preprocess import NetworkFrame
from service.core.profile import load_profile
from service.core.regions import pose_class


def moment_of(file: str) -> str:
    """Key of the moment a photo was taken: the name without a left/right camera prefix."""
    stem = Path(file).stem
    return re.sub(r"^(left|right|l|r)[_-]?", "", stem, flags=re.IGNORECASE) or stem


def split_moments(moments: list[str], seed: int) -> dict[str, str]:
    """Assign each distinct moment to train / val / test (about 60 / 20 / 20 %), seeded.

    val and test get round(20 %) of the moments each, at least one when there are >= 3.
    """
    distinct = sorted(set(moments))
    order = np.random.default_rng(seed).permutation(len(distinct))
    n = len(distinct)
    n_hold = max(1, round(0.2 * n)) if n >= 3 else 0
    names = ["test"] * n_hold + ["val"] * n_hold + ["train"] * (n - 2 * n_hold)
    return {distinct[i]: names[k] for k, i in enumerate(order)}


def rotation(rvec: np.ndarray) -> np.ndarray:
    """OpenCV Rodrigues vector (3,) -> object -> camera rotation R (3, 3)."""
    rot, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))
    return rot


def optical_axis_target(cam: np.ndarray, rvec: np.ndarray | None) -> np.ndarray:
    """Where the optical axis of a camera at `cam` (3,) meets the plane z = 0 (cm).

    `rvec` is the OpenCV Rodrigues vector of the object -> camera rotation; without it, or if
    the axis does not reach the plane in front of the camera, the object centre (0, 0, 0).
    """
    if rvec is None:
        return np.zeros(3)
    axis = rotation(rvec).T @ np.array([0.0, 0.0, 1.0])  # optical axis in the object frame
    if axis[2] >= -1e-9:
        return np.zeros(3)
    return cam + (-cam[2] / axis[2]) * axis


def turned_roll(roll_deg: float) -> float:
    """The camera roll (degrees, [-180, 180)) of a photo turned a quarter clockwise
    (`service.core.preprocess.NetworkFrame`): its content turns by -90 degrees."""
    return (roll_deg + 90.0) % 360.0 - 180.0


def read_rgb(path: Path) -> np.ndarray:
    """Image file -> RGB uint8 [H, W, 3] (grey images get three equal channels)."""
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise ValueError(f"cannot read image {path}")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def build_real_dataset(
    source: Path, out: Path, size: int, blur: int, profile: str, seed: int
) -> dict[str, Any]:
    """Write out/ (images/*.png, labels.csv, manifest.json) from `source`; return the manifest.

    Besides the class, labels.csv gets the target (`optical_axis_target`), the camera roll
    (`service.core.geometry.roll_of_pose`), the focal length relative to the SPEC one when the
    source gives `rvec0..2` and `fx`, `width`, and the pixel aspect of the resized photo.
    """
    prof = load_profile(profile)
    z_split = float(prof.geometry.z_split_cm)
    wh = SIZES[size]
    with (source / "labels.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    if not rows:
        raise ValueError(f"{source / 'labels.csv'} has no rows")
    missing = {"file", "cam_x", "cam_y", "cam_z"} - set(rows[0])
    if missing:
        raise ValueError(f"{source / 'labels.csv'} lacks columns {sorted(missing)}")
    assignment = split_moments([moment_of(r["file"]) for r in rows], seed)

    (out / "images").mkdir(parents=True, exist_ok=True)
    labels = []
    for row in rows:
        cam = np.array([float(row[k]) for k in ("cam_x", "cam_y", "cam_z")])
        rvec = np.array([float(row[f"rvec{i}"]) for i in range(3)]) if "rvec0" in row else None
        target = optical_axis_target(cam, rvec)
        photo = read_rgb(source / row["file"])
        frame = NetworkFrame((photo.shape[1], photo.shape[0]), wh)
        image = blur_image(frame.input_of(photo), blur, wh)
        roll = 0.0 if rvec is None else roll_of_pose(rotation(rvec))
        roll = turned_roll(roll) if frame.turned else roll
        name = f"images/{Path(row['file']).stem}.png"
        cv2.imwrite(str(out / name), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
        focal = ""
        turned = frame.turned and row.get("fy") and row.get("height")
        if row.get("fx") and row.get("width"):  # along the landscape width
            f, w = (row["fy"], row["height"]) if turned else (row["fx"], row["width"])
            focal = f"{focal_scale(float(f), float(w)):.4f}"
        labels.append(
            {
                "file": name,
                "class": int(pose_class(cam, z_split)),
                **{f"cam_{a}": f"{v:.4f}" for a, v in zip("xyz", cam, strict=True)},
                **{f"target_{a}": f"{v:.4f}" for a, v in zip("xyz", target, strict=True)},
                "blur": blur,
                "split": assignment[moment_of(row["file"])],
                "roll_deg": "" if rvec is None else f"{roll:.2f}",
                "focal_scale": focal,
                "pixel_aspect": f"{frame.pixel_aspect:.4f}",
            }
        )
    write_labels(out / LABELS_FILE, labels, [*LABEL_COLUMNS, "pixel_aspect"])
    manifest = {
        "generator": "planar-pose realset",
        "generator_version": "1.0",
        "variant": "real",
        "real": True,
        "source": repo_relative(source),
        "profile": prof.manifest_entry(),
        "size": list(wh),
        "blur": blur,
        "seed": seed,
        "split_by": "moment (stereo pairs stay together)",
    }
    return write_manifest(out, manifest, labels)


#: Columns of a corpus data set: the data set ones, the source, the camera at the set's size
#: and the pixel aspect of the resized photo (`service.core.preprocess.NetworkFrame`).
CORPUS_SET_COLUMNS = [
    *LABEL_COLUMNS, "source", "original", "fx", "fy", "cx", "cy", "k2", "p1", "p2", "k3",
    "pixel_aspect",
]  # fmt: skip


def in_frame(row: dict[str, str], frame: NetworkFrame) -> dict[str, str]:
    """The pixel aspect, camera (fx, fy, cx, cy), object corners and roll of a stored photo's
    labels in the set's images (`frame`: turned to landscape if portrait, then resized, pixel
    centres kept); k1 (normalised coordinates) and the rest unchanged."""
    out = {"pixel_aspect": f"{frame.pixel_aspect:.4f}"}
    if frame.turned and row.get("roll_deg"):
        out["roll_deg"] = f"{turned_roll(float(row['roll_deg'])):.2f}"
    if row.get("corner_x0"):
        uv = frame.to_network(np.array([float(row[c]) for c in CORNER_COLUMNS]).reshape(4, 2))
        out |= dict(zip(CORNER_COLUMNS, (f"{v:.3f}" for v in uv.ravel()), strict=True))
    if not row.get("fx"):
        return out
    f = np.array([float(row["fx"]), float(row["fy"])])
    c = frame.to_network(np.array([float(row["cx"]), float(row["cy"])]))
    f = (f[::-1] if frame.turned else f) * np.asarray(frame.size) / frame.upright_size
    cam = {"fx": f[0], "fy": f[1], "cx": c[0], "cy": c[1]}
    return out | {k: f"{v:.4f}" for k, v in cam.items()}


def build_corpus_dataset(
    corpus: Path, out: Path, size: int, blur: int, profile: str
) -> dict[str, Any]:
    """One data set (SPEC size, blur level) from every source of `corpus`, split by source.

    `corpus/splits.toml` names the split of every source: a source's photos all go to one
    split, so the test split holds cameras and scenes never used for training or selection.
    The images go to the network size as in serving (`service.core.preprocess.NetworkFrame`:
    portraits turned to landscape, the area resize, aspect ratio not kept: the `pixel_aspect`
    column says by how much) and are blurred with the SPEC level.
    """
    prof = load_profile(profile)
    z_split = float(prof.geometry.z_split_cm)
    splits = read_splits(corpus / "splits.toml")
    sources = corpus_sources(corpus)
    missing = [s.name for s in sources if s.name not in splits]
    if missing:
        raise ValueError(f"{corpus / 'splits.toml'} gives no split for: {', '.join(missing)}")
    wh = SIZES[size]
    (out / "images").mkdir(parents=True, exist_ok=True)
    labels = []
    for src in sources:
        with (src / "labels.csv").open(newline="") as fh:
            rows = list(csv.DictReader(fh))
        for row in rows:
            photo = read_rgb(src / row["file"])
            frame = NetworkFrame((photo.shape[1], photo.shape[0]), wh)
            image = blur_image(frame.input_of(photo), blur, wh)
            name = f"images/{src.name}__{Path(row['file']).stem}.png"
            cv2.imwrite(str(out / name), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
            label = {k: row.get(k, "") for k in LABEL_COLUMNS}
            if row.get("cam_z"):
                cam = np.array([float(row[f"cam_{a}"]) for a in "xyz"])
                label["class"] = int(pose_class(cam, z_split))
            label |= {"file": name, "blur": blur, "split": splits[src.name], "source": src.name}
            label |= {"original": row.get("original", "")} | in_frame(row, frame)
            labels.append(label)
    write_labels(out / LABELS_FILE, labels, CORPUS_SET_COLUMNS)
    manifest = {
        "generator": "planar-pose realset (corpus)",
        "generator_version": "1.0",
        "variant": "real",
        "real": True,
        "source": repo_relative(corpus),
        "profile": prof.manifest_entry(),
        "size": list(wh),
        "blur": blur,
        "split_by": "source (corpus/splits.toml)",
        "sources": {s: sorted({r["source"] for r in labels if r["split"] == s}) for s in SPLITS},
    }
    return write_manifest(out, manifest, labels)


def measure_rolls(labels_csv: Path) -> np.ndarray:
    """Rolls (degrees, (N,)) of the photos of a real labels.csv with OpenCV rvec0..2 columns."""
    with Path(labels_csv).open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    if not rows or "rvec0" not in rows[0]:
        raise ValueError(f"{labels_csv}: needs rows with rvec0, rvec1, rvec2 columns")
    rolls = []
    for row in rows:
        rvec = np.array([float(row[f"rvec{i}"]) for i in range(3)])
        R, _ = cv2.Rodrigues(rvec)
        rolls.append(roll_of_pose(R))
    return np.asarray(rolls)
