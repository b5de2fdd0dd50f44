"""Labelling real photographs: chessboard corners, clicked corners, texture matching, errors."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from service.core.dataset import load_dataset
from service.core.frame import texture_to_object
from service.core.geometry import homography_from_pose, intrinsics, look_at, translation
from service.core.paths import ASSETS_DIR
from service.core.profile import load_profile
from service.core.regions import pose_class
from train.cli import app
from train.real.calibration import Calibration, default_camera
from train.real.corners import ChessboardPattern, detect_chessboard
from train.real.label import compare_to_truth, label_folder, read_corner_csv

SOURCE = ASSETS_DIR / "real" / "chessboard-stereo"
runner = CliRunner()


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def labelled(tmp_path_factory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("label") / "real"
    result = runner.invoke(
        app,
        [
            "label", str(SOURCE), str(out), "--calibration", str(SOURCE / "calibration.json"),
            "--truth", str(SOURCE / "labels.csv"),
        ],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    return out, json.loads((out / "manifest.json").read_text())


def test_real_labels_agree_with_the_ground_truth(labelled):
    out, manifest = labelled
    check = compare_to_truth(out, SOURCE / "labels.csv", 60.0)
    assert check["count"] == 26 == manifest["count"]
    assert check["centre_error_cm_mean"] < 1.0
    assert check["centre_error_cm_max"] < 2.0
    assert check["class_agreement"] == 1.0
    assert (out / "failed.txt").read_text() == ""


def test_output_is_a_data_set_with_overlays(labelled):
    out, manifest = labelled
    rows = _rows(out / "labels.csv")
    assert {"file", "class", "cam_x", "target_x", "blur", "split", "fx", "corner_y3"} <= set(
        rows[0]
    )
    for row in rows:
        assert (out / row["file"]).is_file()
        assert row["file"].startswith("images/") and float(row["focal_scale"]) > 0
        overlay = cv2.imread(str(out / "overlays" / f"{Path(row['file']).stem}.png"))
        assert overlay is not None and overlay.shape == (480, 640, 3)
        centre = [float(row[k]) for k in ("cam_x", "cam_y", "cam_z")]
        assert int(row["class"]) == int(pose_class(np.array(centre), 60.0))
    assert manifest["counts"] == {"train": 14, "val": 6, "test": 6}
    test = load_dataset(out, split="test")
    assert test.images.shape == (6, 480, 640, 3) and list(test.labels) == [
        int(r["class"]) for r in rows if r["split"] == "test"
    ]
    # The labelled folder feeds the real-set builder unchanged.
    result = runner.invoke(app, ["realset", str(out), str(out.parent / "s1")])
    assert result.exit_code == 0, result.output


def test_clicked_corners_give_the_same_pose(tmp_path):
    """The ground truth's corners (inner-grid rectangle, 20 x 12.5 cm) as clicked corners."""
    truth = _rows(SOURCE / "labels.csv")[:4]
    images = tmp_path / "images"
    images.mkdir()
    for row in truth:
        (images / row["file"]).write_bytes((SOURCE / row["file"]).read_bytes())
    clicks = tmp_path / "clicks.csv"
    with clicks.open("w", newline="") as fh:
        cols = ["file"] + [f"corner_{a}{i}" for i in range(4) for a in "xy"]
        writer = csv.DictWriter(fh, fieldnames=cols, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(truth)
    profile = load_profile("chessboard")
    inner = type("Inner", (), {})()
    inner.__dict__.update(
        name="chessboard-inner-grid", width_cm=20.0, height_cm=12.5,
        texture=profile.texture, geometry=profile.geometry,
    )  # fmt: skip
    cal = Calibration.load(SOURCE / "calibration.json")
    manifest = label_folder(images, tmp_path / "out", inner, cal, read_corner_csv(clicks))
    assert manifest["methods"] == {"clicked": 4}
    check = compare_to_truth(tmp_path / "out", SOURCE / "labels.csv", 60.0)
    assert check["count"] == 4 and check["centre_error_cm_mean"] < 1.0
    assert check["class_agreement"] == 1.0


def _distinct_texture(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    tex = np.full((280, 400, 3), 255, np.uint8)
    for _ in range(150):
        colour = tuple(int(v) for v in rng.integers(0, 256, 3))
        x, y = (int(v) for v in rng.integers(0, 400, 2))
        if rng.random() < 0.5:
            cv2.circle(tex, (x, y % 280), int(rng.integers(4, 30)), colour, -1)
        else:
            w, h = (int(v) for v in rng.integers(5, 40, 2))
            cv2.rectangle(tex, (x, y % 280), (x + w, y % 280 + h), colour, -1)
    return tex


def test_textured_profile_is_found_by_features(tmp_path):
    """Renders of a non-repetitive texture at known camera centres are labelled by SIFT."""
    texture = _distinct_texture()
    cv2.imwrite(str(tmp_path / "tex.png"), texture)
    profile = type("Poster", (), {})()
    profile.__dict__.update(
        name="poster", width_cm=25.0, height_cm=17.5, texture=tmp_path / "tex.png",
        geometry=load_profile("chessboard").geometry,
    )  # fmt: skip
    images = tmp_path / "images"
    images.mkdir()
    size = (640, 480)
    A = default_camera(size).K
    centres = {"a.png": (12.0, 9.0, 35.0), "b.png": (-15.0, -6.0, 70.0), "c.png": (8.0, -12, 45)}
    to_obj = texture_to_object((400, 280), 25.0, 17.5)
    for name, c in centres.items():
        R = look_at(np.array(c), np.zeros(3))
        H = homography_from_pose(A, R, translation(R, np.array(c))) @ to_obj
        cv2.imwrite(
            str(images / name), cv2.warpPerspective(texture, H, size, borderValue=(90,) * 3)
        )
    cv2.imwrite(str(images / "empty.png"), np.full((480, 640, 3), 90, np.uint8))
    manifest = label_folder(images, tmp_path / "out", profile)
    assert manifest["count"] == 3 and manifest["methods"] == {"sift": 3}
    assert manifest["failed_files"] == ["empty.png: object not found"]
    assert "empty.png" in (tmp_path / "out" / "failed.txt").read_text()
    for row in _rows(tmp_path / "out" / "labels.csv"):
        got = np.array([float(row[k]) for k in ("cam_x", "cam_y", "cam_z")])
        assert np.linalg.norm(got - centres[Path(row["file"]).name]) < 1.0


@pytest.mark.parametrize("turn", [False, True])
def test_colour_parity_fixes_the_orientation(turn):
    """A front view of the board texture: the (-X,-Y) corner is found at the bottom left,
    or at the top right when the picture is turned by half a turn."""
    texture = cv2.imread(str(SOURCE / "texture.png"))
    board = cv2.resize(texture, None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST)
    image = cv2.copyMakeBorder(board, 60, 60, 60, 60, cv2.BORDER_CONSTANT, value=(255,) * 3)
    if turn:
        image = cv2.rotate(image, cv2.ROTATE_180)
    rgb = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    h, w = rgb.shape[:2]
    A = intrinsics((w, h))
    A[0, 2], A[1, 2] = (w - 1) / 2, (h - 1) / 2
    corr = detect_chessboard(rgb, ChessboardPattern(9, 6, 2.5), lambda p: p, A)
    assert corr is not None
    corner = corr.image_uv[np.argmin(corr.object_xy.sum(axis=1))]
    # Inner grid in the enlarged texture: u in [40, 360], v in [40, 240], plus the 60 px margin.
    expected = np.array([100.0, 300.0]) if not turn else np.array([w - 1 - 100.0, h - 1 - 300.0])
    assert np.linalg.norm(corner - expected) < 3.0


def _invoke(*args: str):
    return runner.invoke(app, ["label", *args])


def test_cli_errors(tmp_path):
    result = _invoke(str(tmp_path / "missing"), str(tmp_path / "out"))
    assert result.exit_code == 1 and "not found" in result.output
    (tmp_path / "empty").mkdir()
    result = _invoke(str(tmp_path / "empty"), str(tmp_path / "out"))
    assert result.exit_code == 1 and "no images" in result.output
    result = _invoke(str(SOURCE), str(tmp_path / "out"), "--profile", "no-such-profile")
    assert result.exit_code == 1
    bad = tmp_path / "bad.csv"
    bad.write_text("file,corner_x0\nleft01.jpg,3\n")
    result = _invoke(str(SOURCE), str(tmp_path / "out"), "--corners", str(bad))
    assert result.exit_code == 1 and "missing column" in result.output
    cols = ",".join(f"corner_{a}{i}" for i in range(4) for a in "xy")
    bad.write_text(f"file,{cols}\nleft01.jpg,1,2,3,4,5,6,7,x\n")
    result = _invoke(str(SOURCE), str(tmp_path / "out"), "--corners", str(bad))
    assert result.exit_code == 1 and "numbers" in result.output
    bad.write_text(f"file,{cols}\nnot-there.jpg,1,2,3,4,5,6,7,8\n")
    result = _invoke(str(SOURCE), str(tmp_path / "out"), "--corners", str(bad))
    assert result.exit_code == 1 and "not in" in result.output
    cal = tmp_path / "cal.json"
    cal.write_text('{"K": [[1, 0], [0, 1]]}')
    result = _invoke(str(SOURCE), str(tmp_path / "out"), "--calibration", str(cal))
    assert result.exit_code == 1 and "3x3" in result.output
    cal.write_text("{not json")
    result = _invoke(str(SOURCE), str(tmp_path / "out"), "--calibration", str(cal))
    assert result.exit_code == 1 and "JSON" in result.output


def test_calibration_scales_with_the_image():
    cal = Calibration.load(SOURCE / "calibration.json")
    full = cal.for_image("left01.jpg", (640, 480))
    small = cal.for_image("left01.png", (80, 60))
    assert small.K[0, 0] == pytest.approx(full.K[0, 0] / 8)
    assert small.K[0, 2] == pytest.approx((full.K[0, 2] + 0.5) / 8 - 0.5)
    assert np.array_equal(small.dist, full.dist)
    assert cal.camera_name("right07.jpg") == "right"
    with pytest.raises(ValueError, match="aspect"):
        cal.for_image("left01.jpg", (80, 80))


def _noisy_view(c: tuple[float, float, float], seed: int = 0):
    """The 9 x 6 inner corners seen from camera centre `c` (cm) through a distorting camera,
    with 0.5 px of noise: (grid cm, raw pixels, camera, true R, true t)."""
    from train.real.calibration import Camera
    from train.real.label import project

    K = np.array([[700.0, 0, 330], [0, 700, 235], [0, 0, 1]])
    camera = Camera(K, np.array([-0.35, 0.15, 0.001, -0.002, 0.0]), (640, 480))
    grid = ChessboardPattern(9, 6, 2.5).grid_xy()
    R = look_at(np.array(c), np.zeros(3))
    t = translation(R, np.array(c))
    uv = project(np.column_stack([grid, np.zeros(len(grid))]), R, t, K, camera.dist)
    noisy = uv + np.random.default_rng(seed).normal(0.0, 0.5, uv.shape)
    return grid, noisy, camera, R, t


@pytest.mark.parametrize("c", [(25.0, 18.0, 30.0), (-30.0, 10.0, 45.0), (30.0, 25.0, 70.0)])
def test_refinement_lowers_the_reprojection_error_and_keeps_the_orientation(c):
    from service.core.geometry import camera_centre, dlt_homography, pose_from_homography
    from train.real.corners import Correspondences
    from train.real.label import label_from_points

    grid, uv, camera, R_true, _ = _noisy_view(c)
    lab = label_from_points(Correspondences(grid, uv, "chessboard"), camera, grid[:4], 60.0)
    R0, t0 = pose_from_homography(dlt_homography(grid, camera.undistort(uv)), camera.K)
    dlt_error = np.linalg.norm(camera_centre(R0, t0) - c)
    error = np.linalg.norm(lab.centre - c)
    assert lab.rms < lab.dlt_rms and lab.rms < 0.75  # 0.5 px per axis: about 0.7 px
    assert error < 0.5 and error < 0.6 * dlt_error
    # Same orientation: board normal and in-plane axes as the truth's, class unchanged.
    assert np.all(np.einsum("ij,ij->j", lab.R, R_true) > 0.99)
    assert lab.label == int(pose_class(np.array(c), 60.0))


@pytest.mark.parametrize("bad", ["half turn", "worse", "error"])
def test_refinement_falls_back_to_the_initial_pose(monkeypatch, bad):
    """A refinement that turns the board, reprojects worse or fails leaves the initial pose.

    For "half turn" the points are given in reverse order (the grid is symmetric: they are
    the board turned by half a turn), so the turned pose fits them far better than the
    initial one: only the orientation test refuses it."""
    import train.real.label as label_module
    from service.core.geometry import dlt_homography, pose_from_homography
    from train.real.label import refine_pose, reprojection_rms

    grid, uv, camera, _, _ = _noisy_view((25.0, 18.0, 30.0))
    R0, t0 = pose_from_homography(dlt_homography(grid, camera.undistort(uv)), camera.K)
    turned = R0 @ np.diag([-1.0, -1.0, 1.0])
    if bad == "half turn":
        uv = uv[::-1]
        assert reprojection_rms(grid, uv, turned, t0, camera) < 0.1 * reprojection_rms(
            grid, uv, R0, t0, camera
        )

    def fake(obj, img, K, dist, rvec, tvec, criteria):
        if bad == "error":
            raise cv2.error("no convergence")
        if bad == "half turn":
            return cv2.Rodrigues(turned)[0], tvec
        return rvec + 0.05, tvec * 1.1

    monkeypatch.setattr(label_module.cv2, "solvePnPRefineLM", fake)
    R, t, rms = refine_pose(grid, uv, camera, R0, t0)
    assert np.array_equal(R, R0) and np.array_equal(t, t0)
    assert rms == pytest.approx(reprojection_rms(grid, uv, R0, t0, camera))
