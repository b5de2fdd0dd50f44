"""The pose, the finer regions and the camera store (docs/pose.md) against the real service:
both clients, the stream and the CLI. The service runs with a camera store of its own (a
temporary POSE_CAMERA_DB, live_service.run_service)."""

from __future__ import annotations

import asyncio
import json
import math

import cv2
import httpx
import numpy as np
import pytest
from live_service import MAX_IMAGES, REAL
from planar_pose_client import (
    AsyncPoseClient,
    AuthError,
    CameraNotFoundError,
    InvalidRequestError,
    PoseClient,
)
from planar_pose_client.cli import ExitCode, app
from typer.testing import CliRunner

#: Photos of one camera (the stereo rig's left one, 640x480) and its calibrated focal length.
LEFT = sorted(REAL.glob("left*.jpg"))[:MAX_IMAGES]
CALIBRATED_FX = json.loads((REAL / "calibration.json").read_text())["cameras"]["left"]["K"][0][0]


def within(value: float, bounds: tuple[float, float]) -> bool:
    return bounds[0] - 1e-6 <= value <= bounds[1] + 1e-6


def test_the_pose_of_a_photo_is_consistent(service_url, photos):
    """The fields agree with each other as docs/pose.md defines them: c = -R^T t, distance
    |c|, azimuth atan2(c_y, c_x), elevation asin(c_z / |c|); fx estimated (the corpus photos
    have no EXIF) within its range; the cell holds the pose."""
    with PoseClient(service_url) as client:
        p = client.predict(photos[0], regions="8x3x60")
        sliding = client.predict(photos[0], mode="sliding")
    assert p.present and p.pose is not None and sliding.pose is None
    assert p.image_size == (640, 480)
    pose = p.pose
    rotation, _ = cv2.Rodrigues(np.array(pose.rvec))
    centre = -rotation.T @ np.array(pose.tvec_cm)
    np.testing.assert_allclose(centre, pose.camera_cm, atol=0.05)
    x, y, z = pose.camera_cm
    assert pose.distance_cm == pytest.approx(math.dist(pose.camera_cm, (0, 0, 0)), abs=0.01)
    assert pose.azimuth_deg == pytest.approx(math.degrees(math.atan2(y, x)), abs=0.05)
    assert pose.elevation_deg == pytest.approx(
        math.degrees(math.asin(z / pose.distance_cm)), abs=0.05
    )
    assert pose.fx_source == "estimated" and p.fx is None
    assert pose.fx_range is not None and within(pose.fx, pose.fx_range)
    assert pose.distance_range_cm is not None and within(pose.distance_cm, pose.distance_range_cm)
    assert 0 <= pose.residual_px < 10
    cell = p.cell
    assert cell is not None and cell.grid == "8x3x60"
    low, high = cell.azimuth_deg
    assert (pose.azimuth_deg - low) % 360 <= (high - low) % 360 + 1e-6
    assert within(pose.elevation_deg, cell.elevation_deg)
    assert cell.distance_cm is not None
    assert cell.distance_cm[0] <= pose.distance_cm
    assert cell.distance_cm[1] is None or pose.distance_cm <= cell.distance_cm[1]
    shares = [cell.probability, *(n.probability for n in cell.neighbours)]
    assert all(0 <= s <= 1 for s in shares) and sum(shares) <= 1 + 1e-6
    assert cell.index not in {n.index for n in cell.neighbours}


def test_bad_regions_and_camera_fields_are_422(service_url, photos):
    with PoseClient(service_url, retries=0) as client:
        with pytest.raises(InvalidRequestError, match="regions"):
            client.predict(photos[0], regions="0x3")  # the shape passes, the numbers do not
        # cx, cy need the image's size: the SDK refuses it as the service does, unsent
        with pytest.raises(ValueError, match="give the image's width and height"):
            client.create_camera(1600.0, cx=320.0, cy=240.0)
    for body in ({"fx": 1600.0, "cx": 320.0, "cy": 240.0}, {"fx": True}):
        r = httpx.post(f"{service_url}/v1/cameras", json=body, timeout=30)
        assert r.status_code == 422 and r.json()["error"]["code"] == "invalid_camera", r.text


def test_a_camera_from_intrinsics_create_list_predict_delete(service_url, photos):
    with PoseClient(service_url, retries=0) as client:
        made = client.create_camera(1600.0, name="live-intrinsics")
        assert made.source == "intrinsics" and made.fx == 1600.0 and made.name == "live-intrinsics"
        assert made.id in [c.id for c in client.cameras()]
        assert client.camera(made.id) == made

        with_camera = client.predict(photos[0], camera=made.id)
        pose = with_camera.pose
        assert pose is not None and pose.fx_source == "camera" and pose.fx == 1600.0
        assert pose.fx_range is None and pose.distance_range_cm is None
        assert (with_camera.fx, with_camera.fx_source) == (1600.0, "camera")
        with_fx = client.predict(photos[0], fx=1600.0)
        assert with_fx.pose is not None and with_fx.pose.fx_source == "query"
        assert with_fx.pose.distance_cm == pytest.approx(pose.distance_cm, rel=1e-6)
        assert with_fx.class_id == with_camera.class_id

        # Given at 320 px wide, the camera's fx doubles for the 640 px photos.
        half = client.create_camera(800.0, width=320, height=240)
        scaled = client.predict(photos[0], camera=half.id)
        assert scaled.pose is not None and scaled.pose.fx == pytest.approx(1600.0)

        for camera in (made, half):
            client.delete_camera(camera.id)
        assert not {made.id, half.id} & {c.id for c in client.cameras()}
        with pytest.raises(CameraNotFoundError) as gone:
            client.camera(made.id)
        assert gone.value.status == 404 and made.id in gone.value.message
        with pytest.raises(CameraNotFoundError):
            client.predict(photos[0], camera=made.id)
        with pytest.raises(CameraNotFoundError):
            client.delete_camera(made.id)


def test_learn_a_camera_from_photos(service_url):
    with PoseClient(service_url, retries=0) as client:
        camera = client.learn_camera(LEFT, name="live-left")
        assert camera.source == "photos" and camera.name == "live-left"
        assert (camera.width, camera.height) == (640, 480)
        assert camera.photos_used is not None and 3 <= camera.photos_used <= len(LEFT)
        assert camera.residual_px is not None and camera.residual_px >= 0
        # a focal length of the right size (the rig's calibration, with its lens distortion)
        assert 0.7 < camera.fx / CALIBRATED_FX < 1.4
        p = client.predict(LEFT[0], camera=camera.id)
        assert p.pose is not None and p.pose.fx_source == "camera"
        assert p.pose.fx == pytest.approx(camera.fx)
        with pytest.raises(InvalidRequestError) as too_few:
            client.learn_camera(LEFT[:2])
        assert too_few.value.status == 422 and "3 or more" in too_few.value.message
        client.delete_camera(camera.id)


def test_same_camera_fits_one_focal_length(service_url):
    with PoseClient(service_url) as client:
        joint = client.predict_many(LEFT[:4], same_camera=True)
    poses = [p.pose for p in joint]
    assert all(pose is not None and pose.fx_source == "estimated" for pose in poses)
    assert len({pose.fx for pose in poses if pose}) == 1
    assert len({pose.fx_range for pose in poses if pose}) == 1


def test_async_client_cameras(service_url, photos):
    async def run():
        async with AsyncPoseClient(service_url, retries=0) as client:
            made = await client.create_camera(1500.0, name="live-async")
            listed = [c.id for c in await client.cameras()]
            one = await client.camera(made.id)
            p = await client.predict(photos[0], camera=made.id, regions="4x2")
            await client.delete_camera(made.id)
            with pytest.raises(CameraNotFoundError):
                await client.camera(made.id)
            return made, listed, one, p

    made, listed, one, p = asyncio.run(run())
    assert made.id in listed and one == made
    assert p.pose is not None and p.pose.fx_source == "camera" and p.pose.fx == 1500.0
    assert p.cell is not None and p.cell.grid == "4x2"


def test_the_stream_with_a_camera(service_url, photos):
    with PoseClient(service_url, retries=0) as client:
        made = client.create_camera(1600.0, name="live-stream")
        answers = list(client.stream(photos[:2], camera=made.id))
        assert [a.seq for a in answers] == [0, 1]
        for answer in answers:
            assert answer.ok and answer.pose is not None
            assert answer.pose.fx_source == "camera" and answer.pose.fx == 1600.0
        client.delete_camera(made.id)
        with pytest.raises(CameraNotFoundError) as unknown:
            list(client.stream(photos[:1], camera=made.id))
        assert unknown.value.status == 404 and unknown.value.code == "camera_not_found"


def test_the_stream_learns_its_camera(service_url):
    """Without fx or camera the stream fits fx to the views it has answered, then uses it."""
    with PoseClient(service_url) as client:
        answers = list(client.stream(LEFT * 2))
    sources = [a.pose.fx_source for a in answers if a.ok and a.pose is not None]
    assert len(sources) >= len(LEFT) and sources[0] == "estimated" and sources[-1] == "stream"
    learned = sources.index("stream")
    assert set(sources[learned:]) == {"stream"}


def test_cameras_need_the_api_key(secured_url):
    with PoseClient(secured_url, retries=0) as anonymous, pytest.raises(AuthError):
        anonymous.cameras()


def test_the_cli_cameras_and_pose(service_url, photos):
    runner = CliRunner()

    def invoke(*args: str):
        return runner.invoke(app, [*args, "--url", service_url])

    added = invoke("cameras", "add", "--fx", "1600", "--name", "live-cli", "--json")
    assert added.exit_code == 0, added.output
    camera_id = json.loads(added.stdout)["id"]
    listing = invoke("cameras", "list")
    assert listing.exit_code == 0 and camera_id in listing.stdout and "live-cli" in listing.stdout
    shown = invoke("cameras", "show", camera_id)
    assert shown.exit_code == 0 and "1600.0 px" in shown.stdout
    as_json = invoke("predict", str(photos[0]), "--camera", camera_id, "--json")
    assert as_json.exit_code == 0, as_json.output
    (answer,) = json.loads(as_json.stdout)
    assert answer["pose"]["fx_source"] == "camera" and answer["pose"]["fx"] == 1600.0
    table = invoke("predict", str(photos[0]), "--camera", camera_id, "--regions", "8x3")
    assert table.exit_code == 0, table.output
    assert "camera pose" in table.stdout and "1600 (camera)" in table.stdout
    assert "finer regions, grid 8x3" in table.stdout
    deleted = invoke("cameras", "delete", camera_id)
    assert deleted.exit_code == 0 and camera_id in deleted.stdout
    for result in (invoke("cameras", "show", camera_id), invoke("cameras", "delete", camera_id)):
        assert result.exit_code == ExitCode.UNKNOWN_CAMERA, result.output
        assert result.stderr.startswith("error: HTTP 404 camera_not_found")
    too_few = invoke("cameras", "learn", *map(str, LEFT[:2]))
    assert too_few.exit_code == ExitCode.SERVICE_ERROR and "HTTP 422" in too_few.stderr
    assert "Traceback" not in too_few.output
