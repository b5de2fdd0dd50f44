"""Feature baseline: poses from distinctive textures, class 0 without a homography, tuning,
intrinsics per data set, CLI errors."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from service.core.frame import texture_to_object
from service.core.geometry import homography_from_pose, intrinsics, look_at, translation
from service.core.paths import ASSETS_DIR
from service.core.regions import pose_class
from train.cli import app
from train.compare.baseline import BaselineConfig, FeatureBaseline, dataset_cameras, tune
from train.real.calibration import Camera

REAL = ASSETS_DIR / "real" / "chessboard-stereo"
W_CM, H_CM = 25.0, 17.5
CENTRES = [
    (10, 8, 30), (-10, 8, 30), (-10, -8, 30), (10, -8, 30),
    (15, 10, 70), (-20, 10, 70), (-10, -15, 75), (10, -10, 80),
]  # fmt: skip
runner = CliRunner()


def _texture(seed: int = 0) -> np.ndarray:
    """A non-repetitive RGB texture (random discs and rectangles), 400 x 280."""
    rng = np.random.default_rng(seed)
    tex = np.full((280, 400, 3), 255, np.uint8)
    for _ in range(150):
        colour = tuple(int(v) for v in rng.integers(0, 256, 3))
        x, y = int(rng.integers(0, 400)), int(rng.integers(0, 280))
        if rng.random() < 0.5:
            cv2.circle(tex, (x, y), int(rng.integers(4, 30)), colour, -1)
        else:
            w, h = (int(v) for v in rng.integers(5, 40, 2))
            cv2.rectangle(tex, (x, y), (x + w, y + h), colour, -1)
    return tex


def _render(texture: np.ndarray, centre, size=(160, 120)) -> np.ndarray:
    A = intrinsics(size)
    R = look_at(np.array(centre, float), np.zeros(3))
    H = homography_from_pose(A, R, translation(R, np.array(centre, float)))
    H = H @ texture_to_object((texture.shape[1], texture.shape[0]), W_CM, H_CM)
    return cv2.warpPerspective(texture, H, size, flags=cv2.INTER_AREA, borderValue=(90,) * 3)


@pytest.fixture(scope="module")
def texture() -> np.ndarray:
    return _texture()


@pytest.mark.parametrize("features", ["sift", "orb", "both"])
def test_recovers_the_class_of_renders(texture, features):
    baseline = FeatureBaseline(texture, W_CM, H_CM, 60.0, BaselineConfig(features=features))
    camera = Camera(intrinsics((160, 120)), np.zeros(5))
    right = 0
    for centre in CENTRES:
        pred = baseline.predict(_render(texture, centre), camera)
        right += pred.label == int(pose_class(np.array(centre), 60.0))
        if pred.centre is not None and features == "sift":
            assert np.linalg.norm(pred.centre - centre) < 0.1 * np.linalg.norm(centre)
    assert right >= (7 if features != "orb" else 5)


def test_no_homography_means_class_zero(texture):
    baseline = FeatureBaseline(texture, W_CM, H_CM, 60.0)
    camera = Camera(intrinsics((160, 120)), np.zeros(5))
    blank = baseline.predict(np.full((120, 160, 3), 90, np.uint8), camera)
    assert blank.label == 0 and blank.centre is None and "too few" in blank.reason
    other = baseline.predict(_render(_texture(seed=7), (10, 8, 30)), camera)
    assert other.label == 0 and other.reason


def test_mirrored_view_is_not_a_pose(texture):
    baseline = FeatureBaseline(texture, W_CM, H_CM, 60.0, BaselineConfig(ratio=0.9))
    camera = Camera(intrinsics((160, 120)), np.zeros(5))
    mirrored = _render(texture[:, ::-1].copy(), (10, 8, 30))
    assert baseline.predict(mirrored, camera).label == 0


def test_tuning_uses_the_given_images_only(texture):
    baseline = FeatureBaseline(texture, W_CM, H_CM, 60.0)
    camera = Camera(intrinsics((160, 120)), np.zeros(5))
    images = np.stack([_render(texture, c) for c in CENTRES[:4]])
    labels = pose_class(np.array(CENTRES[:4], float), 60.0)
    tuned, info = tune(baseline, images, labels, [camera] * 4)
    assert len(info["grid"]) == 15 and info["val_accuracy"] == max(info["grid"].values())
    assert info["chosen"]["ratio"] == tuned.config.ratio
    assert tuned.matchers is baseline.matchers  # the texture features are shared


def _write_set(folder: Path, rows: list[dict], manifest: dict) -> None:
    folder.mkdir(parents=True)
    with (folder / "labels.csv").open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    (folder / "manifest.json").write_text(json.dumps(manifest))


def test_dataset_cameras(tmp_path):
    cols = {"file": "a.png", "class": 1, "fx": 100, "fy": 101, "cx": 40, "cy": 30}
    _write_set(tmp_path / "own", [cols], {})
    (cam,) = dataset_cameras(tmp_path / "own", ["a.png"], (80, 60))
    assert cam.K[0, 0] == 100 and cam.K[1, 1] == 101 and cam.K[0, 2] == 40
    rows = [cols, {**cols, "file": "neg.png", "class": 0, "fx": "", "fy": "", "cx": "", "cy": ""}]
    _write_set(tmp_path / "corpus", rows, {})  # a corpus photo without the board: no camera
    cams = dataset_cameras(tmp_path / "corpus", ["a.png", "neg.png"], (80, 60))
    assert cams[0].K[0, 0] == 100 and np.allclose(cams[1].K[:2, :2], intrinsics((80, 60))[:2, :2])

    _write_set(tmp_path / "syn", [{"file": "a.png", "class": 1}], {"variant": "C"})
    (cam,) = dataset_cameras(tmp_path / "syn", ["a.png"], (80, 60))
    assert np.allclose(cam.K, intrinsics((80, 60)))

    rows = [{"file": "a.png", "class": 1, "focal_scale": "0.75"}, {"file": "b.png", "class": 0}]
    rows[1]["focal_scale"] = ""
    _write_set(tmp_path / "zoom", rows, {"variant": "noC"})
    cams = dataset_cameras(tmp_path / "zoom", ["b.png", "a.png"], (160, 120))
    assert np.allclose(cams[1].K, intrinsics((160, 120), 0.75))
    assert np.allclose(cams[0].K, intrinsics((160, 120)))

    real = {"real": True, "source": "train/assets/real/chessboard-stereo"}
    _write_set(tmp_path / "real", [{"file": "right03.png", "class": 1}], real)
    (cam,) = dataset_cameras(tmp_path / "real", ["right03.png"], (80, 60))
    calibration = json.loads((REAL / "calibration.json").read_text())
    fx_right = calibration["cameras"]["right"]["K"][0][0]
    assert cam.K[0, 0] == pytest.approx(fx_right / 8) and np.any(cam.dist)


def test_cli_errors(tmp_path):
    result = runner.invoke(app, ["baseline", str(tmp_path), "--out", str(tmp_path / "o")])
    assert result.exit_code == 1 and "no labels.csv" in result.output
    _write_set(tmp_path / "ds", [{"file": "a.png", "class": 1}], {})
    result = runner.invoke(
        app, ["baseline", str(tmp_path / "ds"), "--out", str(tmp_path / "o"), "--features", "surf"]
    )
    assert result.exit_code == 2 and "--features" in result.output


def test_cli_writes_the_evaluate_layout(tmp_path):
    from train.real.realset import build_real_dataset

    ds = tmp_path / "real-s1-b0"
    build_real_dataset(REAL, ds, size=1, blur=0, profile="chessboard", seed=0)
    args = ["baseline", str(ds), "--out", str(tmp_path / "o"), "--split", "val"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    doc = json.loads((tmp_path / "o" / "metrics.json").read_text())
    cell = doc["results"]["baseline-sift"]["real-s1-b0"]
    assert cell["count"] == 6 and len(cell["confusion"]) == 9 and cell["ms_per_image"] > 0
    assert (tmp_path / "o" / "report.md").is_file()


# The chessboard peer: OpenCV's detector + IPPE PnP + the region rule.


def _stereo_rows(n: int) -> list[dict[str, str]]:
    with (REAL / "labels.csv").open(newline="") as fh:
        return list(csv.DictReader(fh))[:n]


def _peer(enlarge: float = 4):
    from service.core.profile import load_profile
    from train.compare.chessboard_peer import ChessboardPeer
    from train.real.label import chessboard_pattern

    profile = load_profile("chessboard")
    return ChessboardPeer(chessboard_pattern(profile), profile.geometry.z_split_cm, enlarge)


def test_enlarged_camera_keeps_pixel_centres():
    from train.compare.chessboard_peer import enlarge_camera

    cam = Camera(intrinsics((80, 60)), np.array([0.1, 0, 0, 0, 0]))
    big = enlarge_camera(cam, 4, (80, 60))
    expected = Camera(cam.K, cam.dist, (80, 60)).scaled((320, 240))
    assert np.allclose(big.K, expected.K) and big.size == (320, 240)
    assert np.array_equal(big.dist, cam.dist)


def test_chessboard_peer_on_sharp_full_size_photos():
    from train.real.calibration import Calibration
    from train.real.realset import read_rgb

    peer, calibration = _peer(enlarge=1), Calibration.load(REAL / "calibration.json")
    for row in _stereo_rows(4):
        rgb = read_rgb(REAL / row["file"])
        pred = peer.predict(rgb, calibration.for_image(row["file"], (rgb.shape[1], rgb.shape[0])))
        truth = np.array([float(row[k]) for k in ("cam_x", "cam_y", "cam_z")])
        assert pred.label == int(pose_class(truth, 60.0)), row["file"]
        assert np.linalg.norm(pred.centre - truth) < 0.05 * np.linalg.norm(truth)


def test_chessboard_peer_at_the_network_size(tmp_path):
    from train.compare.peers import run_detector_on
    from train.compare.sets import load_part, stored_photos
    from train.real.realset import build_real_dataset

    ds = tmp_path / "real-s2-b0"
    build_real_dataset(REAL, ds, size=2, blur=0, profile="chessboard", seed=0)
    data = load_part(ds, "test")
    metrics, info = run_detector_on(data)
    assert metrics["count"] == 6 and metrics["accuracy"] >= 5 / 6 and metrics["ms_per_image"] > 0
    assert info["tuning"] is None
    photos = stored_photos(data)
    assert photos is not None and [p.parent for p in photos.paths] == [REAL] * 6
    assert photos.cameras[0].size == (640, 480) and np.any(photos.cameras[0].dist)


def test_chessboard_peer_answers_zero_without_a_board():
    from service.core.profile import load_profile
    from train.compare.chessboard_peer import NOT_FOUND
    from train.synth.generate import DatasetSpec, render_in_memory
    from train.synth.render import render_view

    profile = load_profile("chessboard")
    images, labels = render_in_memory(DatasetSpec("noC", 2, 0, 9, 3, profile))
    camera = Camera(intrinsics((160, 120)), np.zeros(5))
    peer = _peer()
    for image in images[labels == 0]:
        pred = peer.predict(image, camera)
        assert pred.label == 0 and pred.centre is None and pred.reason == NOT_FOUND
    for centre in ((10.0, 8.0, 45.0), (20.0, -10.0, 75.0)):  # a board, enlarged 4x: found
        pred = peer.predict(render_view(profile, (160, 120), np.array(centre)), camera)
        assert pred.label == int(pose_class(np.array(centre), 60.0))
        assert np.linalg.norm(pred.centre - centre) < 1.0


def test_stored_photos_of_a_corpus_set(tmp_path):
    from service.core.dataset import load_dataset
    from train.compare.sets import stored_photos

    corpus = tmp_path / "corpus"
    src = corpus / "boards" / "cam1"
    cam = {"width": 64, "height": 48, "fx": 50, "fy": 51, "cx": 31.5, "cy": 23.5}
    cam |= {"k1": 0.1, "k2": 0, "p1": 0, "p2": 0, "k3": 0}
    _write_set(src, [{"file": "images/p1.jpg", "class": 1, **cam}], {})
    (src / "images").mkdir()
    cv2.imwrite(str(src / "images" / "p1.jpg"), np.full((48, 64, 3), 128, np.uint8))
    ds = tmp_path / "set"
    row = {"file": "images/cam1__p1.png", "class": 1, "split": "test", "source": "cam1"}
    _write_set(ds, [row | {"original": "p1.JPG"}], {"real": True, "source": str(corpus),
                                                    "size": [32, 24]})  # fmt: skip
    (ds / "images").mkdir()
    cv2.imwrite(str(ds / "images" / "cam1__p1.png"), np.zeros((24, 32, 3), np.uint8))
    photos = stored_photos(load_dataset(ds))
    assert photos is not None and photos.paths == [src / "images" / "p1.jpg"]
    assert photos.cameras[0].K[0, 0] == 50 and photos.cameras[0].dist[0] == 0.1
    (src / "images" / "p1.jpg").unlink()  # the corpus is not on this machine: no reference
    assert stored_photos(load_dataset(ds)) is None
