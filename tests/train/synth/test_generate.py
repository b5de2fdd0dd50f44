"""Synthetic data sets on disk and the loader: labels, balance, determinism, cache."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from service.core.dataset import DatasetError, load_dataset
from service.core.preprocess import decode_image, resize_rgb
from service.core.profile import load_profile
from train.synth.generate import (
    DatasetSpec,
    balanced_assignment,
    make_dataset,
    plan_dataset,
    render_in_memory,
)

PROFILE = load_profile("chessboard")


def _rows(folder: Path) -> list[dict[str, str]]:
    with (folder / "labels.csv").open(newline="") as fh:
        return list(csv.DictReader(fh))


def _class_of(x: float, y: float, z: float, z_split: float) -> int:
    """SPEC section 3, written out independently of service.core.regions."""
    quadrants = {(True, True): 1, (False, True): 2, (False, False): 3, (True, False): 4}
    quadrant = quadrants[(x >= 0, y >= 0)]
    return quadrant if z < z_split else quadrant + 4


@pytest.fixture(scope="module")
def small_set(tmp_path_factory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("sets") / "noC-s1-b2"
    spec = DatasetSpec("noC", 1, 2, 90, 7, PROFILE)
    return out, make_dataset(out, spec)


def test_manifest_and_files(small_set):
    out, manifest = small_set
    assert json.loads((out / "manifest.json").read_text()) == manifest
    assert manifest["profile"]["name"] == "chessboard"
    assert manifest["profile"]["texture"] == "train/assets/profiles/chessboard/texture.png"
    assert manifest["size"] == [80, 60] and manifest["variant"] == "noC"
    assert (manifest["blur"], manifest["seed"], manifest["count"]) == (2, 7, 90)
    assert manifest["counts"] == {"train": 54, "val": 18, "test": 18}
    assert manifest["split_class_counts"]["test"] == [2] * 9
    rows = _rows(out)
    assert len(rows) == 90
    for row in rows[:5]:
        assert cv2.imread(str(out / row["file"])).shape == (60, 80, 3)


def test_labels_agree_with_the_camera_centres(small_set):
    out, manifest = small_set
    z_split = manifest["profile"]["z_split_cm"]
    for row in _rows(out):
        assert row["blur"] == "2"
        if row["class"] == "0":
            assert row["cam_x"] == row["cam_y"] == row["cam_z"] == ""
            continue
        x, y, z = (float(row[k]) for k in ("cam_x", "cam_y", "cam_z"))
        assert int(row["class"]) == _class_of(x, y, z, z_split)
        assert PROFILE.geometry.contains([[x, y, z]]).all()
        assert abs(float(row["target_x"])) <= 3 and abs(float(row["target_y"])) <= 3


@pytest.mark.parametrize("count", [9, 90, 900, 5000, 5003])
def test_splits_are_class_balanced(count):
    classes, splits = balanced_assignment(count, np.random.default_rng(0))
    sizes = np.bincount(splits, minlength=3)
    assert sizes.sum() == count and abs(sizes[0] - 0.6 * count) <= 1
    totals = np.bincount(classes, minlength=9)
    assert totals.max() - totals.min() <= 1
    for s in range(3):
        per = np.bincount(classes[splits == s], minlength=9)
        assert per.max() - per.min() <= 1
        if count >= 900:
            assert (per.max() - per.min()) / sizes[s] <= 0.01


def test_an_all_train_set_puts_every_image_in_the_train_split():
    spec = DatasetSpec("free", 2, 0, 90, 7, PROFILE)
    split = plan_dataset(spec)
    whole = plan_dataset(DatasetSpec("free", 2, 0, 90, 7, PROFILE, all_train=True))
    assert (whole.splits == 0).all() and (split.splits != 0).any()
    assert np.bincount(whole.classes, minlength=9).tolist() == [10] * 9
    assert [v is None for v in whole.views] == [k == 0 for k in whole.classes]


def test_same_seed_same_bytes_any_worker_count(tmp_path):
    spec = DatasetSpec("C", 1, 0, 300, 11, PROFILE)  # two rendering chunks
    a, b = tmp_path / "a", tmp_path / "b"
    make_dataset(a, spec, workers=1)
    make_dataset(b, spec, workers=2)
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert len(files) == 302
    for f in files:
        assert (a / f).read_bytes() == (b / f).read_bytes(), f
    other = render_in_memory(DatasetSpec("C", 1, 0, 300, 12, PROFILE))[0]
    assert not np.array_equal(other, load_dataset(a).images)


def test_loader_round_trip_and_cache(small_set, tmp_path):
    out, _ = small_set
    data = load_dataset(out, split="train")
    rows = [r for r in _rows(out) if r["split"] == "train"]
    assert data.images.shape == (54, 60, 80, 3) and data.images.dtype == np.uint8
    assert data.labels.dtype == np.int64
    assert data.labels.tolist() == [int(r["class"]) for r in rows]
    first = cv2.cvtColor(cv2.imread(str(out / rows[0]["file"])), cv2.COLOR_BGR2RGB)
    assert np.array_equal(data.images[0], first)
    assert data.column("file") == [r["file"] for r in rows]
    assert (out / ".cache" / "images-80x60.npy").is_file()
    everything = load_dataset(out)  # from the cache now
    assert len(everything.labels) == 90 and data.size == (80, 60)
    margin = data.boundary_margin_cm()
    centres = np.array([[float(r[f"cam_{a}"] or "nan") for a in "xyz"] for r in rows])
    want = np.minimum(np.abs(centres[:, :2]).min(1), np.abs(centres[:, 2] - 60.0))
    shown = data.labels > 0
    assert np.isnan(margin[~shown]).all() and np.allclose(margin[shown], want[shown])
    cut = data.board_cut()
    corners = np.array(
        [[float(r[f"corner_{a}{i}"] or "nan") for i in range(4) for a in "xy"] for r in rows]
    )
    outside = ((corners < 0) | (corners > np.tile([80, 60], 4))).any(1)
    assert np.isnan(cut[~shown]).all() and np.array_equal(cut[shown], outside[shown])


def test_cache_is_invalidated_when_labels_change(tmp_path):
    out = tmp_path / "set"
    make_dataset(out, DatasetSpec("noC", 1, 0, 18, 3, PROFILE))
    before = load_dataset(out)
    rows = _rows(out)
    keep = rows[::2]
    with (out / "labels.csv").open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(keep)
    after = load_dataset(out)
    assert len(after.labels) == 9
    assert np.array_equal(after.images, before.images[::2])


def test_loader_resizes_real_photos_like_the_service(tmp_path):
    out = tmp_path / "real"
    out.mkdir()
    rng = np.random.default_rng(0)
    photo = cv2.GaussianBlur(rng.integers(0, 256, (480, 640, 3), dtype=np.uint8), (0, 0), 3)
    cv2.imwrite(str(out / "p.jpg"), photo)
    (out / "labels.csv").write_text("file,class,split\np.jpg,3,test\n")
    (out / "manifest.json").write_text(json.dumps({"size": [80, 60], "real": True}))
    data = load_dataset(out, split="test")
    expected = resize_rgb(decode_image((out / "p.jpg").read_bytes()), (80, 60))
    assert np.array_equal(data.images[0], expected) and data.labels.tolist() == [3]
    assert load_dataset(out, split="train").images.shape == (0, 60, 80, 3)


def test_loader_errors(tmp_path):
    with pytest.raises(DatasetError, match="not found"):
        load_dataset(tmp_path / "missing")
    with pytest.raises(DatasetError, match="no labels.csv"):
        load_dataset(tmp_path)
    (tmp_path / "labels.csv").write_text("file,class,split\na.png,12,train\n")
    (tmp_path / "manifest.json").write_text('{"size": [80, 60]}')
    with pytest.raises(DatasetError, match="line 2: class must be 0..8"):
        load_dataset(tmp_path)
    (tmp_path / "labels.csv").write_text("file,class,split\na.png,1,train\n")
    with pytest.raises(DatasetError, match="a.png listed in labels.csv is missing"):
        load_dataset(tmp_path)
    (tmp_path / "a.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    with pytest.raises(DatasetError, match="cannot read image a.png"):
        load_dataset(tmp_path)
    (tmp_path / "manifest.json").write_text("{oops")
    with pytest.raises(DatasetError, match="not valid JSON"):
        load_dataset(tmp_path)
    with pytest.raises(DatasetError, match="split must be"):
        load_dataset(tmp_path, split="training")


def test_refuses_to_overwrite(tmp_path):
    spec = DatasetSpec("noC", 1, 0, 9, 0, PROFILE)
    (tmp_path / "notes.txt").write_text("mine")
    with pytest.raises(DatasetError, match="not empty"):
        make_dataset(tmp_path, spec)
    with pytest.raises(DatasetError, match="not a data set folder"):
        make_dataset(tmp_path, spec, overwrite=True)
    assert (tmp_path / "notes.txt").exists()


@pytest.mark.parametrize(
    "args,message",
    [
        (("X", 1, 0, 90), "variant"),
        (("C", 3, 0, 90), "size"),
        (("C", 1, 4, 90), "blur"),
        (("C", 1, 0, 8), "count must be at least 9"),
    ],
)
def test_bad_specs(args, message):
    with pytest.raises(DatasetError, match=message):
        DatasetSpec(*args, seed=0, profile=PROFILE)
