"""The pose, the finer regions and the camera store (docs/pose.md) in the SDK, the stream client
and the CLI, against a fake service behind `httpx.MockTransport` that answers as the contract
says (the live service is driven in test_client_service.py)."""

from __future__ import annotations

import asyncio
import copy
import json
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import httpx
import pytest
from planar_pose_client import (
    AsyncPoseClient,
    Camera,
    CameraCorruptError,
    CameraNotFoundError,
    InvalidRequestError,
    ModelNotFoundError,
    NotFoundError,
    PoseClient,
    PoseConnectionError,
    PoseError,
    Prediction,
)
from planar_pose_client import cli as cli_module
from planar_pose_client.cli import ExitCode, app
from planar_pose_client.errors import error_from_response
from planar_pose_client.stream import StreamPrediction, closed_error, parse_message, stream_url
from typer.testing import CliRunner
from websockets.exceptions import ConnectionClosed
from websockets.frames import Close

REAL = Path(__file__).resolve().parents[3] / "train/assets/real/chessboard-stereo"
PHOTOS = [REAL / name for name in ("left01.jpg", "right05.jpg", "left12.jpg")]
URL = "http://pose.test"
FAST: dict[str, Any] = {"backoff": 0.01, "backoff_max": 0.05}

# The examples of docs/pose.md, verbatim.
POSE = {
    "camera_cm": [12.1, -30.4, 48.9],
    "distance_cm": 58.8,
    "azimuth_deg": -68.3,
    "elevation_deg": 56.3,
    "rvec": [2.31, 0.41, -0.22],
    "tvec_cm": [-1.2, 3.4, 58.6],
    "fx": 1480.2,
    "fx_source": "estimated",
    "fx_range": [1310.0, 1702.4],
    "distance_range_cm": [52.1, 67.3],
    "residual_px": 0.8,
}
CELL = {
    "grid": "8x3x60",
    "index": 13,
    "azimuth_deg": [22.5, 67.5],
    "elevation_deg": [30.0, 60.0],
    "distance_cm": [0.0, 60.0],
    "label": "az 22.5..67.5, el 30..60, d 0..60",
    "probability": 0.81,
    "neighbours": [{"index": 12, "probability": 0.12}, {"index": 21, "probability": 0.07}],
}
CAMERA = {
    "id": "c-3f2a9b1c",
    "name": "left",
    "fx": 1402.3,
    "fy": None,
    "cx": None,
    "cy": None,
    "dist": None,
    "width": 1920,
    "height": 1080,
    "source": "photos",
    "photos_used": 9,
    "residual_px": 0.7,
    "created": "2026-12-05T09:12:03Z",
}


def result(filename: str, **extra: Any) -> dict[str, Any]:
    """One whole-mode result of class 6 (far, x-, y+), as an older service sends it."""
    probabilities = [0.02] * 9
    probabilities[6] = 0.84
    return {
        "filename": filename,
        "class_id": 6,
        "region": {"present": True, "depth": "far", "x": "-", "y": "+", "label": "far, x-, y+"},
        "probabilities": probabilities,
        "confidence": 0.84,
        "box": None,
        "corners": [[10.0, 20.0], [110.0, 20.0], [110.0, 90.0], [10.0, 90.0]],
        "elapsed_ms": 1.5,
        **extra,
    }


def error(status: int, code: str, message: str) -> httpx.Response:
    return httpx.Response(status, json={"error": {"code": code, "message": message}})


@dataclass
class FakeService:
    """/v1/predict and /v1/cameras as docs/pose.md describes them, cameras kept in a dict;
    `requests` records what the client sent."""

    cameras: dict[str, dict[str, Any]] = field(default_factory=dict)
    requests: list[httpx.Request] = field(default_factory=list)
    with_pose: bool = True

    def __call__(self, request: httpx.Request) -> httpx.Response:
        request.read()
        self.requests.append(request)
        path, query = request.url.path, request.url.params
        if path in ("/v1/predict", "/v1/models/chessboard-corners-160x120/predict"):
            return self.predict(request)
        if path.startswith("/v1/models/"):
            return error(404, "model_not_found", "no model named 'nope'; served: a, b")
        if path == "/v1/cameras" and request.method == "GET":
            newest_first = sorted(self.cameras.values(), key=lambda c: c["created"])[::-1]
            return httpx.Response(200, json={"cameras": newest_first})
        if path == "/v1/cameras" and request.method == "POST":
            if request.headers["content-type"].startswith("multipart/"):
                photos = request.content.count(b'name="image"')
                if photos < 3:
                    return error(
                        422,
                        "camera_not_learned",
                        f"{photos} photo(s) show the object; a camera needs 3 or more",
                    )
                body = {"fx": 1402.3, "width": 640, "height": 480, "name": query.get("name")}
                return self.store(body, source="photos", photos_used=photos, residual_px=0.7)
            return self.store(json.loads(request.content), source="intrinsics")
        if path.startswith("/v1/cameras/"):
            camera_id = path.rsplit("/", 1)[1]
            if camera_id not in self.cameras:
                return error(404, "camera_not_found", f"no camera {camera_id!r}")
            if request.method == "DELETE":
                del self.cameras[camera_id]
                return httpx.Response(204)
            return httpx.Response(200, json=self.cameras[camera_id])
        return error(404, "not_found", "Not Found")

    def store(self, body: dict[str, Any], **fields: Any) -> httpx.Response:
        camera_id = f"c-{len(self.cameras) + 1:08x}"
        camera = {k: None for k in CAMERA} | {"photos_used": 0} | body | fields
        camera |= {"id": camera_id, "created": f"2026-12-05T09:12:{len(self.cameras):02d}Z"}
        self.cameras[camera_id] = camera
        return httpx.Response(201, json=camera)

    def predict(self, request: httpx.Request) -> httpx.Response:
        query = request.url.params
        names = [
            part.split(b'filename="', 1)[1].split(b'"', 1)[0].decode()
            for part in request.content.split(b"Content-Disposition")[1:]
        ]
        if "fx" in query and "camera" in query:
            return error(422, "invalid_parameters", "fx and camera: give one")
        camera = query.get("camera")
        if camera is not None and camera not in self.cameras:
            return error(404, "camera_not_found", f"no camera {camera!r}")
        results = []
        for name in names:
            extra: dict[str, Any] = {}
            if self.with_pose:
                pose = copy.deepcopy(POSE)
                if camera is not None:
                    pose |= {"fx": self.cameras[camera]["fx"], "fx_source": "camera"}
                    pose |= {"fx_range": None, "distance_range_cm": None}
                    extra |= {"fx": pose["fx"], "fx_source": "camera"}
                extra["pose"] = pose
                if "regions" in query:
                    extra["cell"] = CELL | {"grid": query["regions"]}
            results.append(result(name, **extra))
        return httpx.Response(200, json={"model": "fake", "mode": "whole", "results": results})

    def last_query(self) -> dict[str, str]:
        return dict(self.requests[-1].url.params)


@pytest.fixture
def fake() -> FakeService:
    return FakeService()


def sync_client(fake: FakeService, **kw: Any) -> PoseClient:
    return PoseClient(URL, transport=httpx.MockTransport(fake), **kw)


# --- the answer models --------------------------------------------------------------------


def test_the_documented_pose_and_cell_parse():
    p = Prediction.model_validate(result("a.jpg", pose=POSE, cell=CELL))
    assert p.pose is not None and p.cell is not None
    assert p.pose.camera_cm == (12.1, -30.4, 48.9) and p.pose.tvec_cm == (-1.2, 3.4, 58.6)
    assert (p.pose.distance_cm, p.pose.azimuth_deg, p.pose.elevation_deg) == (58.8, -68.3, 56.3)
    assert p.pose.fx == 1480.2 and p.pose.fx_source == "estimated"
    assert p.pose.fx_range == (1310.0, 1702.4) and p.pose.distance_range_cm == (52.1, 67.3)
    assert p.cell.index == 13 and p.cell.azimuth_deg == (22.5, 67.5)
    assert p.cell.distance_cm == (0.0, 60.0) and p.cell.probability == 0.81
    assert [(n.index, n.probability) for n in p.cell.neighbours] == [(12, 0.12), (21, 0.07)]
    assert p.model_dump(mode="json")["pose"] == POSE  # nothing lost on the way back
    assert p.image_size is None
    assert Prediction.model_validate(result("a.jpg", image_size=[640, 480])).image_size == (
        640,
        480,
    )


def test_answers_of_older_and_newer_services_parse():
    old = Prediction.model_validate(result("a.jpg"))
    assert old.pose is None and old.cell is None
    known = POSE | {"fx_range": None, "distance_range_cm": None, "fx_source": "camera"}
    newer = Prediction.model_validate(
        result("a.jpg", fx=1400.0, fx_source="camera", pose=known | {"later": 1}, extra=2)
    )
    assert newer.fx_source == "camera" and newer.pose is not None
    assert newer.pose.fx_range is None and newer.pose.distance_range_cm is None
    last_band = Prediction.model_validate(
        result("a.jpg", pose=POSE, cell=CELL | {"distance_cm": [120.0, None], "neighbours": []})
    )
    assert last_band.cell is not None and last_band.cell.distance_cm == (120.0, None)
    with pytest.raises(ValueError, match="fx_source"):
        Prediction.model_validate(result("a.jpg", pose=POSE | {"fx_source": "guess"}))


def test_the_documented_camera_parses():
    camera = Camera.model_validate(CAMERA)
    assert camera.id == "c-3f2a9b1c" and camera.fx == 1402.3 and camera.source == "photos"
    assert (camera.width, camera.height, camera.photos_used) == (1920, 1080, 9)
    assert camera.created == datetime(2026, 12, 5, 9, 12, 3, tzinfo=UTC)


# --- predict with a camera, regions, same_camera -------------------------------------------


def test_predict_sends_camera_regions_and_same_camera(fake):
    with sync_client(fake) as c:
        camera = c.create_camera(1400.0, width=640, height=480)
        p = c.predict(PHOTOS[0], camera=camera.id, regions="8x3x60")
        assert fake.last_query() == {"mode": "whole", "camera": camera.id, "regions": "8x3x60"}
        assert p.pose is not None and p.pose.fx_source == "camera" and p.pose.fx == 1400.0
        assert p.cell is not None and p.cell.grid == "8x3x60"
        many = c.predict_many(PHOTOS, same_camera=True, regions="8x3")
        assert fake.last_query() == {"mode": "whole", "regions": "8x3", "same_camera": "true"}
        assert [q.filename for q in many] == [p.name for p in PHOTOS]
        c.predict(PHOTOS[0], fx=1600.0)
        assert fake.last_query() == {"mode": "whole", "fx": "1600.0"}


def test_bad_pose_arguments_fail_before_sending(fake):
    with sync_client(fake) as c:
        with pytest.raises(ValueError, match="fx or camera, not both"):
            c.predict(PHOTOS[0], fx=1400.0, camera="c-1")
        for grid in ("8", "8x", "8x3x", "8x3x60;120", "8 x 3", "8x3 ", "８x３"):
            with pytest.raises(ValueError, match="regions must be AxE"):
                c.predict(PHOTOS[0], regions=grid)
        for camera_id in ("", "../v1/model", "c 1"):
            with pytest.raises(ValueError, match="not a camera id"):
                c.predict(PHOTOS[0], camera=camera_id)
    assert fake.requests == []


def test_an_unknown_camera_on_predict_is_camera_not_found(fake):
    with sync_client(fake, retries=0) as c:
        with pytest.raises(CameraNotFoundError) as unknown:
            c.predict(PHOTOS[0], camera="c-nope")
        assert unknown.value.status == 404 and unknown.value.code == "camera_not_found"
        assert unknown.value.message == "no camera 'c-nope'"
        with pytest.raises(ModelNotFoundError) as model:  # a missing model stays what it was
            c.predict(PHOTOS[0], model="nope")
        assert not isinstance(model.value, CameraNotFoundError)
        assert isinstance(model.value, NotFoundError)


# --- the camera store -----------------------------------------------------------------------


def test_a_corrupt_camera_is_camera_corrupt_error() -> None:
    message = "camera 'c-1' is stored corrupt: DELETE /v1/cameras/c-1 clears it (...)"

    def corrupt(request: httpx.Request) -> httpx.Response:
        return error(409, "camera_corrupt", message)

    transport = httpx.MockTransport(corrupt)
    with (
        PoseClient(URL, retries=0, transport=transport, **FAST) as c,
        pytest.raises(CameraCorruptError) as got,
    ):
        c.camera("c-1")
    assert got.value.status == 409 and got.value.message == message
    full = httpx.Response(409, json={"error": {"code": "camera_store_full", "message": "x"}})
    assert type(error_from_response(full)) is PoseError  # another 409: not about one camera


def test_create_list_get_and_delete_cameras(fake):
    with sync_client(fake) as c:
        first = c.create_camera(1400.0, width=1920, height=1080, name="left")
        assert json.loads(fake.requests[-1].content) == {
            "fx": 1400.0,
            "width": 1920,
            "height": 1080,
            "name": "left",
        }
        second = c.create_camera(
            900, fy=905.5, cx=320, cy=240.5, dist=[0.1, -0.2, 0.0, 0.0, 0.05], width=640, height=480
        )
        assert json.loads(fake.requests[-1].content) == {
            "fx": 900.0,
            "fy": 905.5,
            "cx": 320.0,
            "cy": 240.5,
            "dist": [0.1, -0.2, 0.0, 0.0, 0.05],
            "width": 640,
            "height": 480,
        }
        assert first.source == second.source == "intrinsics" and first.name == "left"
        assert [cam.id for cam in c.cameras()] == [second.id, first.id]  # newest first
        assert c.camera(first.id) == first
        assert c.delete_camera(first.id) is None
        assert fake.requests[-1].method == "DELETE"
        assert [cam.id for cam in c.cameras()] == [second.id]
        with pytest.raises(CameraNotFoundError) as gone:
            c.camera(first.id)
        assert gone.value.status == 404 and first.id in gone.value.message
        with pytest.raises(CameraNotFoundError):
            c.delete_camera(first.id)


def test_learn_a_camera_from_photos(fake):
    with sync_client(fake) as c:
        camera = c.learn_camera(PHOTOS, model="chessboard-corners-160x120", name="stereo")
        sent = fake.requests[-1]
        assert sent.method == "POST" and sent.url.path == "/v1/cameras"
        assert dict(sent.url.params) == {"model": "chessboard-corners-160x120", "name": "stereo"}
        assert sent.content.count(b'name="image"') == 3
        for photo in PHOTOS:
            assert f'filename="{photo.name}"'.encode() in sent.content
        assert camera.source == "photos" and camera.photos_used == 3 and camera.name == "stereo"
        with pytest.raises(InvalidRequestError) as too_few:
            c.learn_camera(PHOTOS[:2])
        assert too_few.value.status == 422 and too_few.value.code == "camera_not_learned"
        assert "needs 3 or more" in too_few.value.message
        assert str(too_few.value).startswith("HTTP 422 camera_not_learned: 2 photo(s)")


def test_bad_camera_arguments_fail_before_sending(fake):
    with sync_client(fake) as c:
        for fx in (0, -1.0, float("nan"), float("inf"), "1400", True):
            with pytest.raises(ValueError, match="fx must be a positive number of pixels"):
                c.create_camera(fx)  # type: ignore[arg-type]
        with pytest.raises(ValueError, match="cx must be a finite number"):
            c.create_camera(1400, cx=float("nan"))
        with pytest.raises(ValueError, match="dist must be a non-empty list"):
            c.create_camera(1400, dist=[])
        with pytest.raises(ValueError, match="width must be a whole number of pixels"):
            c.create_camera(1400, width=0)
        with pytest.raises(ValueError, match="height must be a whole number of pixels"):
            c.create_camera(1400, height=480.5)  # type: ignore[arg-type]
        # the service's rules: real cameras only
        for kwargs, message in [
            ({"cx": 1e300, "cy": 1, "width": 640, "height": 480}, "cx: must lie within the image"),
            ({"cx": 320}, "give the image's width and height"),
            ({"width": 640}, "width and height: give both or neither"),
            ({"fy": 9000}, "fy / fx: must lie within 0.5 to 2"),
            ({"dist": [1e300, 0, 0, 0]}, "k1 must lie within"),
            ({"dist": [0, 0, 0, 0, 0, 0]}, "4, 5 or 8 coefficients"),
            ({"fy": 1e9}, "fy: Input should be less than or equal to 100000"),
            ({"name": "x" * 101}, "name: String should have at most 100 characters"),
        ]:
            with pytest.raises(ValueError, match="not a camera the service takes") as refused:
                c.create_camera(1400, **kwargs)  # type: ignore[arg-type]
            assert message in str(refused.value)
        with pytest.raises(TypeError, match="takes a list of photos"):
            c.learn_camera(PHOTOS[0])  # type: ignore[arg-type]
        with pytest.raises(ValueError, match="needs photos"):
            c.learn_camera([])
        with pytest.raises(FileNotFoundError, match="no such image file"):
            c.learn_camera([*PHOTOS, REAL / "missing.jpg"])
        with pytest.raises(ValueError, match="not a model name"):
            c.learn_camera(PHOTOS, model="../x")
        for camera_id in ("../model", "", "a/b"):
            with pytest.raises(ValueError, match="not a camera id"):
                c.camera(camera_id)
            with pytest.raises(ValueError, match="not a camera id"):
                c.delete_camera(camera_id)
    assert fake.requests == []


def test_a_camera_is_not_created_twice_by_a_retry():
    """A POST whose answer was lost may have stored the camera: not retried. One that never
    left (connection refused) and 503 answers are."""
    attempts: list[httpx.Request] = []

    def lost(request: httpx.Request) -> httpx.Response:
        attempts.append(request)
        raise httpx.RemoteProtocolError("server disconnected", request=request)

    with PoseClient(URL, retries=3, transport=httpx.MockTransport(lost), **FAST) as c:
        with pytest.raises(PoseConnectionError, match=r"\(1 attempt\)"):
            c.create_camera(1400.0)
        assert len(attempts) == 1
        with pytest.raises(PoseConnectionError):
            c.cameras()  # a read is retried
        assert len(attempts) == 5

    fake = FakeService()
    refused: list[httpx.Request] = []

    def flaky(request: httpx.Request) -> httpx.Response:
        refused.append(request)
        if len(refused) == 1:
            raise httpx.ConnectError("connection refused", request=request)
        if len(refused) == 2:
            return error(503, "not_ready", "loading")
        return fake(request)

    with PoseClient(URL, retries=3, transport=httpx.MockTransport(flaky), **FAST) as c:
        assert c.create_camera(1400.0).fx == 1400.0
    assert len(refused) == 3 and len(fake.cameras) == 1


def test_async_client_cameras_and_pose(fake):
    async def run() -> tuple[Any, ...]:
        transport = httpx.MockTransport(fake)
        async with AsyncPoseClient(URL, transport=transport) as c:
            made = await c.create_camera(1400.0, width=640, height=480, name="a")
            learned = await c.learn_camera(PHOTOS, name="b")
            listing = await c.cameras()
            one = await c.camera(made.id)
            p = await c.predict(PHOTOS[0], camera=made.id, regions="4x2")
            many = await c.predict_many(PHOTOS, same_camera=True)
            await c.delete_camera(learned.id)
            with pytest.raises(CameraNotFoundError):
                await c.camera(learned.id)
            with pytest.raises(InvalidRequestError):
                await c.learn_camera(PHOTOS[:1])
            return made, learned, listing, one, p, many, await c.cameras()

    made, learned, listing, one, p, many, after = asyncio.run(run())
    assert [cam.id for cam in listing] == [learned.id, made.id] and one == made
    assert p.pose.fx_source == "camera" and p.cell.grid == "4x2"
    assert len(many) == 3 and all(q.pose is not None for q in many)
    assert [cam.id for cam in after] == [made.id]


# --- the stream -------------------------------------------------------------------------------


def test_the_stream_url_carries_the_camera_or_fx():
    base = "http://127.0.0.1:8000"
    assert stream_url(base, "whole", 0.0, None, camera="c-1") == (
        "ws://127.0.0.1:8000/v1/stream?mode=whole&camera=c-1"
    )
    assert stream_url("https://h", "whole", 0.5, "m", fx=1400) == (
        "wss://h/v1/stream?mode=whole&smooth=0.5&model=m&fx=1400.0"
    )
    with pytest.raises(ValueError, match="fx or camera, not both"):
        stream_url(base, "whole", 0.0, None, fx=1400, camera="c-1")
    with pytest.raises(ValueError, match="not a camera id"):
        stream_url(base, "whole", 0.0, None, camera="c/1")
    with pytest.raises(ValueError, match="fx must be a positive"):
        stream_url(base, "whole", 0.0, None, fx=-1)


def test_stream_messages_carry_the_pose_and_refusals_name_the_camera():
    learned = POSE | {"fx_source": "stream", "fx_range": None, "distance_range_cm": None}
    item = parse_message(json.dumps(result("frame", seq=4, pose=learned)))
    assert isinstance(item, StreamPrediction) and item.seq == 4
    assert item.pose is not None and item.pose.fx_source == "stream"
    unknown = ConnectionClosed(Close(4404, "camera_not_found"), None)
    camera = closed_error(unknown, ("camera_not_found", "no camera 'c-x'"), "ws://h")
    assert isinstance(camera, CameraNotFoundError) and camera.message == "no camera 'c-x'"
    model = closed_error(unknown, ("model_not_found", "no model named 'm'"), "ws://h")
    assert isinstance(model, ModelNotFoundError) and model.status == 404
    corrupt = ConnectionClosed(Close(4409, "camera 'c-x' is stored corrupt"), None)
    refused = closed_error(corrupt, ("camera_corrupt", "camera 'c-x' is stored corrupt"), "ws://h")
    assert isinstance(refused, CameraCorruptError) and refused.status == 409


# --- the command line ---------------------------------------------------------------------


runner = CliRunner()


@pytest.fixture
def cli_fake(fake, monkeypatch) -> FakeService:
    """The CLI's PoseClient talks to `fake`."""

    def client(*args: Any, **kw: Any) -> PoseClient:
        return PoseClient(*args, transport=httpx.MockTransport(fake), **kw)

    monkeypatch.setattr(cli_module, "PoseClient", client)
    return fake


def invoke(*args: str):
    return runner.invoke(app, [*args, "--url", URL])


def assert_one_line_error(result, code: ExitCode, text: str) -> None:
    assert result.exit_code == code, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and text in lines[0], result.stderr
    assert "Traceback" not in result.output


def test_cli_predict_shows_the_pose(cli_fake):
    table = invoke("predict", *map(str, PHOTOS[:2]))
    assert table.exit_code == 0, table.output
    assert "camera pose" in table.stdout and "fx px (from)" in table.stdout
    for text in ("58.8 (52-67)", "-68", "56", "1480 (estimated)", "0.8", "far, x-, y+"):
        assert text in table.stdout, text
    assert "finer regions" not in table.stdout  # no --regions
    as_json = invoke("predict", str(PHOTOS[0]), "--json")
    assert as_json.exit_code == 0, as_json.output
    (answer,) = json.loads(as_json.stdout)
    assert answer["pose"] == POSE and answer["cell"] is None


def test_cli_predict_with_camera_regions_and_same_camera(cli_fake):
    added = invoke("cameras", "add", "--fx", "1500", "--json")
    camera_id = json.loads(added.stdout)["id"]
    result = invoke("predict", str(PHOTOS[0]), "--camera", camera_id, "--regions", "8x3x60")
    assert result.exit_code == 0, result.output
    assert cli_fake.last_query() == {"mode": "whole", "camera": camera_id, "regions": "8x3x60"}
    assert "1500 (camera)" in result.stdout
    assert "finer regions, grid 8x3x60" in result.stdout
    assert "az 22.5..67.5" in result.stdout and "81%" in result.stdout
    assert "12 12%, 21 7%" in result.stdout
    joint = invoke("predict", *map(str, PHOTOS), "--same-camera", "--json")
    assert joint.exit_code == 0, joint.output
    assert cli_fake.last_query() == {"mode": "whole", "same_camera": "true"}
    assert len(json.loads(joint.stdout)) == 3


def test_cli_predict_pose_errors(cli_fake):
    sent = len(cli_fake.requests)
    split = invoke("predict", *map(str, PHOTOS), "--same-camera", "--batch", "2")
    assert_one_line_error(split, ExitCode.USAGE, "--same-camera fits one focal length")
    both = invoke("predict", str(PHOTOS[0]), "--fx", "1400", "--camera", "c-1")
    assert_one_line_error(both, ExitCode.BAD_INPUT, "give fx or camera, not both")
    grid = invoke("predict", str(PHOTOS[0]), "--regions", "eight")
    assert_one_line_error(grid, ExitCode.BAD_INPUT, "regions must be AxE or AxExD1,D2")
    assert len(cli_fake.requests) == sent
    unknown = invoke("predict", str(PHOTOS[0]), "--camera", "c-nope")
    assert_one_line_error(unknown, ExitCode.UNKNOWN_CAMERA, "HTTP 404 camera_not_found")


def test_cli_without_pose_keeps_the_old_table(cli_fake):
    cli_fake.with_pose = False
    result = invoke("predict", str(PHOTOS[0]))
    assert result.exit_code == 0, result.output
    assert "fx px" in result.stdout and "camera pose" not in result.stdout


def test_cli_cameras_commands(cli_fake):
    empty = invoke("cameras", "list")
    assert empty.exit_code == 0 and "0 camera(s)" in empty.stdout
    added = invoke(
        "cameras", "add", "--fx", "1400", "--width", "1920", "--height", "1080",
        "--cx", "960", "--cy", "540", "--dist", "0.1,-0.2,0,0,0.05", "--name", "left",
    )  # fmt: skip
    assert added.exit_code == 0, added.output
    assert json.loads(cli_fake.requests[-1].content) == {
        "fx": 1400.0,
        "cx": 960.0,
        "cy": 540.0,
        "dist": [0.1, -0.2, 0.0, 0.0, 0.05],
        "width": 1920,
        "height": 1080,
        "name": "left",
    }
    (made,) = cli_fake.cameras.values()
    for text in (made["id"], "left", "1400.0 px", "960.0, 540.0 px", "1920x1080", "intrinsics"):
        assert text in added.stdout, text
    learned = invoke("cameras", "learn", *map(str, PHOTOS), "--name", "stereo", "--json")
    assert learned.exit_code == 0, learned.output
    camera = json.loads(learned.stdout)
    assert camera["source"] == "photos" and camera["photos_used"] == 3
    listing = invoke("cameras", "list")
    assert listing.exit_code == 0 and "2 camera(s)" in listing.stdout
    assert made["id"] in listing.stdout and camera["id"] in listing.stdout
    assert "photos (3)" in listing.stdout
    as_json = json.loads(invoke("cameras", "list", "--json").stdout)
    assert [c["id"] for c in as_json] == [camera["id"], made["id"]]
    shown = invoke("cameras", "show", camera["id"])
    assert shown.exit_code == 0 and "stereo" in shown.stdout and "0.70 px" in shown.stdout
    deleted = invoke("cameras", "delete", camera["id"])
    assert deleted.exit_code == 0 and deleted.stdout.strip() == f"deleted camera {camera['id']}"
    assert list(cli_fake.cameras) == [made["id"]]


def test_cli_cameras_errors(cli_fake):
    assert_one_line_error(
        invoke("cameras", "show", "c-nope"), ExitCode.UNKNOWN_CAMERA, "no camera 'c-nope'"
    )
    assert_one_line_error(
        invoke("cameras", "delete", "c-nope"), ExitCode.UNKNOWN_CAMERA, "HTTP 404"
    )
    assert_one_line_error(invoke("cameras", "show", "../x"), ExitCode.BAD_INPUT, "not a camera id")
    too_few = invoke("cameras", "learn", str(PHOTOS[0]))
    assert_one_line_error(too_few, ExitCode.SERVICE_ERROR, "HTTP 422 camera_not_learned")
    missing = invoke("cameras", "learn", *map(str, PHOTOS), "nope.jpg")
    assert_one_line_error(missing, ExitCode.BAD_INPUT, "no such image file: nope.jpg")
    dist = invoke("cameras", "add", "--fx", "1400", "--dist", "0.1,x")
    assert_one_line_error(dist, ExitCode.USAGE, "--dist takes numbers separated by commas")
    no_fx = invoke("cameras", "add")
    assert no_fx.exit_code == ExitCode.USAGE and "--fx" in no_fx.output
    assert "Traceback" not in no_fx.output
    bad_fx = invoke("cameras", "add", "--fx", "-5")
    assert bad_fx.exit_code == ExitCode.USAGE and "Traceback" not in bad_fx.output


# --- watch ------------------------------------------------------------------------------------


class FakeStreamClient:
    """Stands in for PoseClient in `watch`: answers every frame with a pose."""

    calls: list[dict[str, Any]] = []

    def __init__(self, *args: Any, **kw: Any) -> None:
        pass

    def __enter__(self) -> FakeStreamClient:
        return self

    def __exit__(self, *exc_info: object) -> None:
        pass

    def stream(self, frames, mode, smooth, model, window, *, fx=None, camera=None):
        FakeStreamClient.calls.append({"fx": fx, "camera": camera, "mode": mode})
        source = "camera" if camera else "stream"
        pose = POSE | {"fx_source": source, "fx_range": None, "distance_range_cm": None}
        for seq, _frame in enumerate(frames):
            yield StreamPrediction.model_validate(result(None, seq=seq, pose=pose, cell=CELL))


def test_watch_shows_the_pose_and_passes_the_camera(monkeypatch, tmp_path):
    cv2 = pytest.importorskip("cv2")
    video = tmp_path / "three.mp4"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 5, (640, 480))
    for _ in range(3):
        writer.write(cv2.imread(str(PHOTOS[0])))
    writer.release()
    monkeypatch.setattr(cli_module, "PoseClient", FakeStreamClient)
    FakeStreamClient.calls.clear()
    drawn = tmp_path / "drawn.mp4"
    lines = invoke("watch", str(video), "--camera", "c-1", "--out", str(drawn))
    assert lines.exit_code == 0, lines.output
    assert FakeStreamClient.calls == [{"fx": None, "camera": "c-1", "mode": "whole"}]
    frame_lines = [ln for ln in lines.stdout.splitlines() if ln.startswith("frame")]
    assert len(frame_lines) == 3
    assert "d 58.8 cm  az -68  el 56  fx 1480 (camera)" in frame_lines[0]
    assert "cell 13 (81%)" in frame_lines[0]
    assert drawn.stat().st_size > 0
    as_json = invoke("watch", str(video), "--fx", "1400", "--json")
    assert as_json.exit_code == 0, as_json.output
    answers = [json.loads(ln) for ln in as_json.stdout.splitlines()]
    assert len(answers) == 3 and answers[0]["pose"]["fx_source"] == "stream"
    assert FakeStreamClient.calls[-1]["fx"] == 1400.0
    both = invoke("watch", str(video), "--fx", "1400", "--camera", "c-1")
    assert_one_line_error(both, ExitCode.USAGE, "give --fx or --camera, not both")


def test_pose_error_types_stay_pose_errors():
    assert issubclass(CameraNotFoundError, NotFoundError) and issubclass(NotFoundError, PoseError)
    assert issubclass(ModelNotFoundError, NotFoundError)
