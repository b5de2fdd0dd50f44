"""The real-photo corpus: labelling a staged source, the independent check, sets split by source."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from service.core.dataset import load_dataset
from service.core.paths import ASSETS_DIR
from service.core.profile import load_profile
from train.cli import app
from train.real.corpus import STORE_MAX_SIDE, import_negatives, label_source, read_source
from train.real.label import compare_to_truth
from train.real.realset import build_corpus_dataset

STEREO = ASSETS_DIR / "real" / "chessboard-stereo"
BACKGROUNDS = ASSETS_DIR / "backgrounds" / "photos"
runner = CliRunner()


def _stage(root: Path, name: str, files: list[Path], enlarge: float = 1.0) -> Path:
    """A staged source folder: images/ (optionally enlarged), LICENSE, source.json."""
    src = root / name
    (src / "images").mkdir(parents=True)
    for f in files:
        image = cv2.imread(str(f))
        if enlarge != 1.0:
            image = cv2.resize(image, None, fx=enlarge, fy=enlarge, interpolation=cv2.INTER_CUBIC)
        cv2.imwrite(str(src / "images" / f.name), image)
    (src / "LICENSE").write_text("Apache License 2.0 (test copy)\n")
    meta = {"repo": "opencv/opencv", "commit": "0" * 40, "folder": "samples/data",
            "licence": "Apache-2.0", "camera": name}  # fmt: skip
    (src / "source.json").write_text(json.dumps(meta))
    return src


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    """A corpus of two board sources (left: 13 photos, enlarged 1.5x so that storing
    downscales them; right: 4 photos, too few to calibrate) and one source without boards."""
    tmp = tmp_path_factory.mktemp("corpus")
    profile = load_profile("chessboard")
    root = tmp / "corpus"
    left = _stage(tmp / "staged", "left", sorted(STEREO.glob("left*.jpg")), enlarge=1.5)
    right = _stage(tmp / "staged", "right", sorted(STEREO.glob("right*.jpg"))[:4])
    negatives = _stage(
        tmp / "staged", "negatives", [*sorted(BACKGROUNDS.glob("*.jpg"))[:3], STEREO / "left01.jpg"]
    )
    manifests = {
        "left": label_source(left, root / "boards" / "left", profile),
        "right": label_source(right, root / "boards" / "right", profile),
        "negatives": import_negatives(negatives, root / "negatives" / "negatives", profile),
    }
    (root / "splits.toml").write_text(
        '[splits]\nleft = "train"\nright = "test"\nnegatives = "val"\n'
    )
    return root, manifests


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


def test_board_source_is_calibrated_labelled_and_stored_small(corpus):
    root, manifests = corpus
    m = manifests["left"]
    assert m["count"] == 13 and m["failed"] == 0
    (cal,) = m["calibration"]
    assert cal["method"].startswith("calibrateCamera") and cal["rms_px"] < 0.5
    assert cal["size"] == [960, 720]
    rows = _rows(root / "boards" / "left" / "labels.csv")
    image = cv2.imread(str(root / "boards" / "left" / rows[0]["file"]))
    assert max(image.shape[:2]) == STORE_MAX_SIDE and rows[0]["width"] == "640"
    # The camera centres match the shipped ground truth of these photos.
    check = compare_to_truth(root / "boards" / "left", STEREO / "labels.csv", 60.0)
    assert check["count"] == 13 and check["centre_error_cm_mean"] < 0.5
    assert check["class_agreement"] == 1.0
    assert (root / "boards" / "left" / "LICENSE").is_file()
    assert (root / "boards" / "left" / "overlays.jpg").is_file()


def test_few_views_fit_the_focal_length_only(corpus):
    _, manifests = corpus
    (cal,) = manifests["right"]["calibration"]
    assert cal["method"].startswith("focal length from 4 homographies")
    assert cal["method"].endswith(", k1") and cal["dist_k1k2p1p2k3"][1:] == [0.0] * 4
    assert 480 < cal["K"][0][0] < 590  # the true fx is 532 px, k1 -0.3
    assert manifests["right"]["count"] == 4


def test_negatives_refuse_a_photo_with_the_board(corpus):
    root, manifests = corpus
    m = manifests["negatives"]
    assert m["count"] == 3 and m["failed"] == 1
    failed = (root / "negatives" / "negatives" / "failed.txt").read_text()
    assert "left01.jpg: a chessboard is found in it" in failed
    assert {r["class"] for r in _rows(root / "negatives" / "negatives" / "labels.csv")} == {"0"}


def test_data_set_is_split_by_source_with_corners_at_the_set_size(corpus, tmp_path):
    root, _ = corpus
    manifest = build_corpus_dataset(root, tmp_path / "s2b1", size=2, blur=1, profile="chessboard")
    assert manifest["counts"] == {"train": 13, "val": 3, "test": 4}
    assert manifest["sources"]["test"] == ["right"]
    data = load_dataset(tmp_path / "s2b1")
    assert data.images.shape == (20, 120, 160, 3)
    left = [r for r in data.rows if r["source"] == "left"]
    assert {r["split"] for r in left} == {"train"}
    stored = {r["file"]: r for r in _rows(root / "boards" / "left" / "labels.csv")}
    for r in left:
        original = stored[f"images/{Path(r['original']).stem}.jpg"]
        for c in ("corner_x0", "corner_y2"):  # 640 x 480 stored -> 160 x 120
            assert float(r[c]) == pytest.approx((float(original[c]) + 0.5) / 4 - 0.5, abs=2e-3)
    assert float(left[0]["fx"]) == pytest.approx(532 * 160 / 640, rel=0.02)


def test_unassigned_source_is_an_error(corpus, tmp_path):
    root, _ = corpus
    copy = tmp_path / "c"
    shutil.copytree(root, copy)
    (copy / "splits.toml").write_text('[splits]\nleft = "train"\n')
    with pytest.raises(ValueError, match="gives no split for: right"):
        build_corpus_dataset(copy, tmp_path / "x", size=1, blur=0, profile="chessboard")


def test_cli_check_report_and_errors(corpus, tmp_path):
    root, _ = corpus
    result = runner.invoke(app, ["corpus", "check", "--corpus", str(root)])
    assert result.exit_code == 0, result.output
    assert "17 / 17" in result.output.replace("\n", " ") or "agrees on 100.0 %" in result.output
    result = runner.invoke(app, ["corpus", "report", "--corpus", str(root)])
    assert result.exit_code == 0, result.output
    readme = (root / "README.md").read_text()
    assert "| `left` |" in readme and "**test** sources: `right`" in readme
    assert "Photos read: the 17 stored photos" in " ".join(readme.split())
    assert (root / "sheets" / "class-0.jpg").is_file()
    bad = tmp_path / "bad"
    (bad / "images").mkdir(parents=True)
    result = runner.invoke(app, ["corpus", "add", str(bad), "--corpus", str(tmp_path / "o")])
    assert result.exit_code == 1 and "no source.json" in result.output
    with pytest.raises(FileNotFoundError, match="no LICENSE"):
        (bad / "source.json").write_text(json.dumps({"repo": "a/b", "commit": "c", "folder": "f",
                                                     "licence": "MIT"}))  # fmt: skip
        read_source(bad)
    result = runner.invoke(app, ["corpus", "sets", str(tmp_path / "s"), "--size", "3"])
    assert result.exit_code == 2 and "--size must be 1 (80x60) or 2" in result.output


def _board_image(extended: bool) -> tuple[np.ndarray, object]:
    """A camera 50 cm above the board looking down (10 px per cm) and its image: the 10 x 7
    squares on white paper, or (extended) a checker pattern that goes on over the frame."""
    from train.real.calibration import Camera
    from train.real.label import Label

    v, u = np.mgrid[0:480, 0:640]
    x, y = (u - 320) / 10, (240 - v) / 10  # cm on the board
    i, j = np.floor((x + 12.5) / 2.5), np.floor((y + 8.75) / 2.5)
    image = np.where((i + j) % 2 == 0, 20, 235).astype(np.uint8)  # black at (-X, -Y)
    if not extended:
        image[(np.abs(x) > 12.5) | (np.abs(y) > 8.75)] = 235
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    R, t = np.diag([1.0, -1.0, -1.0]), np.array([0.0, 0.0, 50.0])
    return image, Label(R, t, np.array([0, 0, 50.0]), 1, None, Camera(K, np.zeros(5)), "", 54, 0)


def test_a_grid_inside_a_bigger_board_is_recognised():
    from train.real.corners import ChessboardPattern
    from train.real.corpus import pattern_continues

    pattern = ChessboardPattern(9, 6, 2.5)
    whole, label = _board_image(extended=False)
    bigger, _ = _board_image(extended=True)
    assert not pattern_continues(whole, label, pattern)
    assert pattern_continues(bigger, label, pattern)


def test_the_shipped_corpus_keeps_its_test_cameras_apart():
    """Every source has a split; the test split has >= 4 board sources and >= 120 board
    photos, from repositories that no train or val source comes from."""
    from service.core.dataset import corpus_sources, read_splits

    corpus = ASSETS_DIR / "real" / "corpus"
    splits = read_splits(corpus / "splits.toml")
    repos: dict[str, set[str]] = {"train": set(), "val": set(), "test": set()}
    test_sources = test_photos = 0
    for folder in corpus_sources(corpus):
        manifest = json.loads((folder / "manifest.json").read_text())
        split = splits[folder.name]
        repos[split].add(manifest["source"]["repo"].lower())
        if split == "test" and folder.parent.name == "boards":
            test_sources += 1
            test_photos += int(manifest["count"])
    assert test_sources >= 4 and test_photos >= 120
    assert not repos["test"] & (repos["train"] | repos["val"])
