"""Real photos -> data set: labels from the camera centres, split by stereo moment."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from service.core.dataset import CORNER_COLUMNS, load_dataset
from service.core.geometry import look_at, project_points, roll_of_pose, translation
from service.core.paths import ASSETS_DIR
from service.core.preprocess import NetworkFrame
from service.core.regions import pose_class
from train.cli import app
from train.real.realset import (
    build_real_dataset,
    in_frame,
    moment_of,
    optical_axis_target,
    split_moments,
)

SOURCE = ASSETS_DIR / "real" / "chessboard-stereo"
runner = CliRunner()


def _rows(folder: Path) -> list[dict[str, str]]:
    with (folder / "labels.csv").open(newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def real_s1(tmp_path_factory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("real") / "s1b0"
    return out, build_real_dataset(SOURCE, out, size=1, blur=0, profile="chessboard", seed=0)


def test_labels_come_from_the_camera_centres(real_s1):
    out, manifest = real_s1
    rows, source = _rows(out), {r["file"]: r for r in _rows(SOURCE)}
    assert len(rows) == 26 == manifest["count"]
    z_split = manifest["profile"]["z_split_cm"]
    for row in rows:
        src = source[Path(row["file"]).stem + ".jpg"]
        cam = [float(src[k]) for k in ("cam_x", "cam_y", "cam_z")]
        assert int(row["class"]) == int(pose_class(np.array(cam), z_split))
        image = cv2.imread(str(out / row["file"]))
        assert image.shape == (60, 80, 3)
    assert manifest["size"] == [80, 60] and manifest["real"] is True
    loaded = load_dataset(out, split="test")
    assert loaded.images.shape == (6, 60, 80, 3) and set(loaded.labels) <= {1, 2, 3, 4}
    focal = {float(r["focal_scale"]) for r in rows}
    assert all(0.6 < f < 0.7 for f in focal)  # fx = 532 px at 640 wide vs the SPEC 206 at 160


def test_stereo_pairs_share_a_split(real_s1):
    out, manifest = real_s1
    by_moment: dict[str, set[str]] = {}
    for row in _rows(out):
        by_moment.setdefault(moment_of(row["file"]), set()).add(row["split"])
    assert len(by_moment) == 13
    assert all(len(s) == 1 for s in by_moment.values())
    assert manifest["counts"] == {"train": 14, "val": 6, "test": 6}


def test_split_is_seeded():
    moments = [f"{i:02d}" for i in range(13)]
    assert split_moments(moments, 0) == split_moments(moments, 0)
    assert split_moments(moments, 0) != split_moments(moments, 1)
    assert moment_of("left07.jpg") == moment_of("right07.jpg") == "07"


def test_target_is_where_the_optical_axis_meets_the_board():
    cam = np.array([0.0, 0.0, 40.0])
    rvec = np.array([np.pi, 0.0, 0.0])  # camera z axis = world -z: looking straight down
    np.testing.assert_allclose(optical_axis_target(cam, rvec), [0, 0, 0], atol=1e-9)
    np.testing.assert_allclose(
        optical_axis_target(np.array([5.0, 0, 40]), rvec), [5, 0, 0], atol=1e-9
    )


def test_blur_changes_the_images(real_s1, tmp_path):
    out0, _ = real_s1
    out3 = tmp_path / "s1b3"
    build_real_dataset(SOURCE, out3, size=1, blur=3, profile="chessboard", seed=0)
    a = cv2.imread(str(out0 / "images" / "left01.png")).astype(float)
    b = cv2.imread(str(out3 / "images" / "left01.png")).astype(float)
    assert np.abs(np.diff(b, axis=1)).mean() < np.abs(np.diff(a, axis=1)).mean()
    assert json.loads((out3 / "manifest.json").read_text())["blur"] == 3


def test_cli(tmp_path):
    out = tmp_path / "r2"
    result = runner.invoke(app, ["realset", str(SOURCE), str(out), "--size", "2"])
    assert result.exit_code == 0, result.output
    assert cv2.imread(str(out / "images" / "right14.png")).shape == (120, 160, 3)
    result = runner.invoke(app, ["realset", str(tmp_path / "none"), str(out)])
    assert result.exit_code == 1 and "no labels.csv" in result.output
    result = runner.invoke(app, ["realset", str(SOURCE), str(out), "--size", "3"])
    assert result.exit_code == 2 and "--size must be 1" in result.output


def test_a_portrait_photo_labels_follow_the_turn_to_landscape() -> None:
    """A 480x640 portrait turned to the 160x120 landscape input: its corners, camera and
    roll are those of the same camera rolled by -90 degrees, seen at 160x120."""
    centre, roll = np.array([10.0, -5.0, 50.0]), 30.0
    half = np.array([12.5, 8.75])
    board = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]]) * [*half, 0]

    def view(size: tuple[int, int], f: float, roll_deg: float) -> tuple[np.ndarray, np.ndarray]:
        A = np.array([[f, 0, (size[0] - 1) / 2], [0, f, (size[1] - 1) / 2], [0, 0, 1.0]])
        R = look_at(centre, np.zeros(3), np.radians(roll_deg))
        return A, project_points(A, R, translation(R, centre), board)

    A, uv = view((480, 640), 500.0, roll)
    row = {"fx": "500", "fy": "500", "cx": f"{A[0, 2]}", "cy": f"{A[1, 2]}"}
    row |= {"roll_deg": f"{roll}", **dict(zip(CORNER_COLUMNS, map(str, uv.ravel()), strict=True))}
    got = in_frame(row, NetworkFrame((480, 640), (160, 120)))
    assert float(got["roll_deg"]) == pytest.approx(
        roll_of_pose(look_at(centre, np.zeros(3), np.radians(roll))) - 90, abs=0.01
    )
    A2, uv2 = view((160, 120), 500.0 / 4, roll - 90)  # 640 -> 160
    assert np.allclose([float(got[c]) for c in CORNER_COLUMNS], uv2.ravel(), atol=1e-2)
    fx, fy, cx, cy = (float(got[k]) for k in ("fx", "fy", "cx", "cy"))
    assert np.allclose([fx, fy, cx, cy], [A2[0, 0], A2[1, 1], A2[0, 2], A2[1, 2]], atol=1e-3)
    assert float(got["pixel_aspect"]) == pytest.approx(1.0)
