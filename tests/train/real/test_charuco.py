"""ChArUco labelling (train/real/charuco.py): the shipped texture, the object frame of the
detector's corners, poses recovered from synthetic views, the CLI and its errors."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from charuco_views import PROFILE, SPEC, K, view
from typer.testing import CliRunner

from service.core.profile import load_profile
from service.core.regions import pose_class
from train.cli import app
from train.real.calibration import Camera
from train.real.charuco import (
    CharucoError,
    CharucoFinder,
    board_texture,
    charuco_spec,
    label_video_source,
    read_camera_array,
)


def test_the_shipped_texture_is_opencvs_board_inverted() -> None:
    assert SPEC is not None and SPEC.squares == (4, 5) and SPEC.inverted
    shipped = cv2.cvtColor(cv2.imread(str(PROFILE.texture)), cv2.COLOR_BGR2RGB)
    np.testing.assert_array_equal(shipped, board_texture(SPEC))
    assert shipped.shape[:2] == (540, 432)  # 27 x 21.6 cm at 20 px per cm
    assert charuco_spec(load_profile("chessboard")) is None


@pytest.mark.parametrize("centre", [(12.0, 9.0, 45.0), (-15.0, -8.0, 75.0), (20.0, -14.0, 38.0)])
def test_detected_corners_give_the_pose_in_the_object_frame(centre) -> None:
    from service.core.frame import object_corners
    from train.real.label import label_from_points

    corr = CharucoFinder(SPEC).find(view(centre))
    assert corr is not None and len(corr.image_uv) >= 10
    lab = label_from_points(corr, Camera(K, np.zeros(5)), object_corners(21.6, 27.0), 60.0)
    # within 3 % of the distance: a mirrored or turned frame would be off by tens of cm
    assert np.linalg.norm(lab.centre - np.array(centre)) < 0.03 * np.linalg.norm(centre)
    assert lab.label == int(pose_class(centre, 60.0))


def test_a_photo_without_the_board_gives_no_correspondences() -> None:
    assert CharucoFinder(SPEC).find(np.full((720, 1280, 3), 128, np.uint8)) is None


def _staged(folder: Path, centres: list[tuple[float, float, float]]) -> Path:
    (folder / "images").mkdir(parents=True)
    for k, c in enumerate(centres):
        cv2.imwrite(str(folder / "images" / f"frame-{k:04d}.png"), view(c)[:, :, ::-1])
    cv2.imwrite(str(folder / "images" / "frame-0099.png"), np.full((720, 1280, 3), 60, np.uint8))
    (folder / "source.json").write_text(
        json.dumps({"repo": "x/y", "commit": "abc", "folder": "v.mp4", "licence": "MIT"})
    )
    (folder / "LICENSE").write_text("MIT")
    return folder


def test_label_video_source_writes_a_corpus_folder(tmp_path: Path) -> None:
    centres = [(12.0, 9.0, 45.0), (-15.0, -8.0, 75.0)]
    src = _staged(tmp_path / "stage", centres)
    m = label_video_source(src, tmp_path / "out", PROFILE, Camera(K, np.zeros(5), (1280, 720)))
    assert m["count"] == 2 and m["photos"] == 3
    assert m["failed_by_reason"] == {"fewer than 6 ChArUco corners": 1}
    assert (
        m["class_counts"]
        == np.bincount([int(pose_class(c, 60.0)) for c in centres], minlength=9).tolist()
    )
    assert m["texture_check"]["found"] >= 1
    assert m["texture_check"]["class_agrees"] == m["texture_check"]["found"]
    stored = cv2.imread(str(tmp_path / "out" / "images" / "frame-0000.jpg"))
    assert stored.shape == (360, 640, 3)
    assert (tmp_path / "out" / "LICENSE").is_file() and (
        tmp_path / "out" / "overlays.jpg"
    ).is_file()


def test_cli_frames_and_charuco(tmp_path: Path) -> None:
    runner = CliRunner()
    video = tmp_path / "v.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 6, (1280, 720))
    for c in [(12.0, 9.0, 45.0), (-15.0, -8.0, 75.0), (20.0, -14.0, 38.0)]:
        writer.write(view(c)[:, :, ::-1].copy())
    writer.release()
    src = _staged(tmp_path / "stage", [])
    shutil.rmtree(src / "images")
    result = runner.invoke(app, ["corpus", "frames", str(video), str(src / "images")])
    assert result.exit_code == 0, result.output
    assert len(list((src / "images").glob("*.png"))) == 3
    cameras = tmp_path / "camera_array.toml"
    cameras.write_text(
        "[cameras.0]\nsize = [1280, 720]\n"
        f"matrix = {K.tolist()}\ndistortions = [0.0, 0.0, 0.0, 0.0, 0.0]\n"
    )
    args = ["corpus", "charuco", str(src), str(tmp_path / "out"), "--camera-array", str(cameras)]
    result = runner.invoke(app, [*args, "--cam", "0"])
    assert result.exit_code == 0, result.output
    assert "3 of 3 frames labelled" in result.output
    result = runner.invoke(app, [*args, "--cam", "4"])
    assert result.exit_code == 2 and "no camera 4" in result.output
    cameras.write_text("not = [toml")
    result = runner.invoke(app, [*args, "--cam", "0"])
    assert result.exit_code == 1 and "not a camera_array.toml" in result.output
    result = runner.invoke(app, ["corpus", "frames", str(tmp_path / "none.mp4"), str(tmp_path)])
    assert result.exit_code == 1 and "video not found" in result.output


def test_bad_charuco_tables_are_refused(tmp_path: Path) -> None:
    folder = tmp_path / "board"
    shutil.copytree(PROFILE.path.parent, folder)
    text = (folder / "profile.toml").read_text()
    (folder / "profile.toml").write_text(text.replace("square_cm = 5.4", "square_cm = 5.0"))
    with pytest.raises(CharucoError, match="the squares measure 20 x 25 cm"):
        charuco_spec(load_profile(folder))
    (folder / "profile.toml").write_text(text.replace("DICT_4X4_1000", "DICT_NOPE"))
    with pytest.raises(CharucoError, match="unknown dictionary"):
        charuco_spec(load_profile(folder))
    with pytest.raises(CharucoError, match="not a camera_array.toml"):
        read_camera_array(folder / "profile.toml")
