"""`/v1/cameras` (docs/pose.md): cameras from intrinsics or photos, kept in SQLite, used by
`?camera=`; hostile input gets a clear 4xx and stores nothing. The stream's learned camera."""

from __future__ import annotations

import json
import logging
import os
import sqlite3
from collections.abc import Iterator
from contextlib import closing
from pathlib import Path

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient
from planar_pose_client import models as sdk_models
from pydantic import ValidationError
from service_support import AppFactory
from starlette.websockets import WebSocketDisconnect
from test_service_pose import ROWS, photo

from service.cameras import schema as schemas
from service.cameras.store import CameraStore
from service.core.paths import ASSETS_DIR
from service.metrics import Metrics

NEGATIVES = sorted(
    (ASSETS_DIR / "real/corpus/negatives/ageitgey__face_recognition/images").iterdir()
)


def cameras(client: TestClient) -> list[dict]:
    r = client.get("/v1/cameras")
    assert r.status_code == 200
    found: list[dict] = r.json()["cameras"]
    return found


def test_a_camera_from_intrinsics_is_stored_listed_used_and_deleted(
    app_factory: AppFactory, tmp_path: Path
) -> None:
    with app_factory(camera_db=tmp_path / "c.db") as c:
        r = c.post("/v1/cameras", json={"fx": 2848.26, "width": 1280, "height": 856, "name": "L"})
        assert r.status_code == 201, r.text
        camera = r.json()
        assert camera["source"] == "intrinsics" and camera["id"].startswith("c-")
        assert c.get(f"/v1/cameras/{camera['id']}").json() == camera
        assert [k["id"] for k in cameras(c)] == [camera["id"]]
        # the photos are 640 px wide: the camera's fx is scaled to them
        r = c.post(f"/v1/predict?camera={camera['id']}", files=[photo(ROWS[0])])
        result = r.json()["results"][0]
        assert result["fx_source"] == "camera" and result["pose"]["fx_source"] == "camera"
        assert result["fx"] == pytest.approx(2848.26 / 2)
        assert c.delete(f"/v1/cameras/{camera['id']}").status_code == 204
        assert cameras(c) == []
        gone = c.post(f"/v1/predict?camera={camera['id']}", files=[photo(ROWS[0])])
        assert gone.status_code == 404 and gone.json()["error"]["code"] == "camera_not_found"


def test_a_camera_learned_from_photos_has_their_focal_length(
    app_factory: AppFactory, tmp_path: Path
) -> None:
    with app_factory(camera_db=tmp_path / "c.db") as c:
        r = c.post("/v1/cameras?name=left", files=[photo(row) for row in ROWS[1:11]])
        assert r.status_code == 201, r.text
        camera = r.json()
        assert camera["source"] == "photos" and camera["name"] == "left"
        assert (camera["width"], camera["height"]) == (640, 428)
        assert camera["fx"] == pytest.approx(float(ROWS[0]["fx"]), rel=0.10)
        assert 3 <= camera["photos_used"] <= 10 and camera["residual_px"] < 4.0
        lo, hi = camera["fx_range"]
        assert lo <= camera["fx"] <= hi


def test_portrait_photos_of_the_camera_learn_with_the_landscape_ones(
    app_factory: AppFactory, tmp_path: Path
) -> None:
    """A phone turned: a photo turned a quarter is the same lens (fx), not another camera."""
    files = [photo(row) for row in ROWS[1:11]]
    for i in (1, 4, 7):
        name, data, kind = files[i][1]
        turned = cv2.rotate(cv2.imdecode(np.frombuffer(data, np.uint8), 1), cv2.ROTATE_90_CLOCKWISE)
        files[i] = ("image", (name, cv2.imencode(".jpg", turned)[1].tobytes(), kind))
    with app_factory(camera_db=tmp_path / "c.db") as c:
        r = c.post("/v1/cameras", files=files)
    assert r.status_code == 201, r.text
    camera = r.json()
    assert (camera["width"], camera["height"]) == (640, 428)
    assert camera["fx"] == pytest.approx(float(ROWS[0]["fx"]), rel=0.10)


def test_cameras_survive_a_restart_and_every_process_sees_them(
    app_factory: AppFactory, tmp_path: Path
) -> None:
    db = tmp_path / "shared.db"
    with app_factory(camera_db=db) as one, app_factory(camera_db=db) as other:
        made = one.post("/v1/cameras", json={"fx": 900}).json()
        assert other.get(f"/v1/cameras/{made['id']}").json() == made
    with app_factory(camera_db=db) as again:
        assert [k["id"] for k in cameras(again)] == [made["id"]]


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ({"fx": -3}, "fx: Input should be greater than or equal to 1"),
        ({"fx": 1e9}, "fx: Input should be less than or equal to 100000"),
        ({"fx": "wide"}, "fx: Input should be a valid number"),
        ({"fy": 900}, "fx: Field required"),
        ({"fx": 900, "width": 640}, "width and height: give both or neither"),
        ({"fx": 900, "cx": 320}, "give the image's width and height"),
        ({"fx": 900, "dist": [0.1]}, "dist: List should have at least 4 items"),
        ({"fx": 900, "lens": "50mm"}, "lens: Extra inputs are not permitted"),
        # strict types: no booleans or strings for numbers, no fractions for sizes
        ({"fx": True}, "fx: Input should be a valid number"),
        ({"fx": "900"}, "fx: Input should be a valid number"),
        ({"fx": 900, "dist": [True, 0, 0, 0]}, "dist.0: Input should be a valid number"),
        ({"fx": 900, "width": 640.0, "height": 480}, "width: Input should be a valid integer"),
        ({"fx": 900, "width": True, "height": 480}, "width: Input should be a valid integer"),
        ({"fx": 900, "name": 5}, "name: Input should be a valid string"),
        # bounds of real cameras
        (
            {"fx": 900, "width": 640, "height": 480, "cx": 1e300, "cy": 240},
            "cx: must lie within the image (0 to 640 px), got 1e+300",
        ),
        (
            {"fx": 900, "width": 640, "height": 480, "cx": 320, "cy": -5},
            "cy: must lie within the image (0 to 480 px)",
        ),
        ({"fx": 900, "fy": 3000}, "fy / fx: must lie within 0.5 to 2"),
        ({"fx": 900, "dist": [1e300, 0, 0, 0]}, "dist: k1 must lie within +-10"),
        ({"fx": 900, "dist": [0, 0, 0, 0, 0, 0, 0, 1e300]}, "dist: k6 must lie within +-100"),
        ({"fx": 900, "dist": [0.1, 0, 0.5, 0]}, "dist: p1 must lie within +-0.1"),
        ({"fx": 900, "dist": [0.1, 0, 0, 0, 0, 0]}, "OpenCV's 4, 5 or 8 coefficients"),
        ({"fx": 900, "dist": [0.1] * 9}, "dist: List should have at most 8 items"),
    ],
)
def test_nonsense_intrinsics_are_a_422_and_store_nothing(
    client: TestClient, body: dict, message: str
) -> None:
    before = cameras(client)
    r = client.post("/v1/cameras", json=body)
    assert r.status_code == 422 and message in r.json()["error"]["message"], r.text
    assert cameras(client) == before


@pytest.mark.parametrize(
    "text",
    [
        b'{"fx":',
        b'{"fx": NaN}',
        b'{"fx": Infinity}',
        b'{"fx": 1e400}',
        b'{"fx": 900, "dist": [NaN, 0, 0, 0]}',
        b'{"fx": 900, "width": 640, "height": 480, "cx": -Infinity, "cy": 1}',
        b"[]",
        b"\xff\xfe",
    ],
)
def test_a_body_that_is_not_a_camera_is_a_422(client: TestClient, text: bytes) -> None:
    r = client.post("/v1/cameras", content=text, headers={"content-type": "application/json"})
    assert r.status_code == 422 and r.json()["error"]["code"] == "invalid_camera"


def test_a_real_calibration_is_stored_as_given(client: TestClient) -> None:
    """OpenCV's calibration of its own sample camera (left01.jpg ...): 5 coefficients."""
    given = {
        "fx": 532.4,
        "fy": 532.4,
        "cx": 341.7,
        "cy": 232.7,
        "dist": [-0.3045, 0.1414, 0.000864, 0.000388, 0],
        "width": 640,
        "height": 480,
    }
    r = client.post("/v1/cameras", json=given)
    assert r.status_code == 201, r.text
    assert {k: r.json()[k] for k in given} == given


def test_photos_without_the_object_or_too_few_are_a_422(client: TestClient) -> None:
    before = cameras(client)
    faces = [("image", (p.name, p.read_bytes(), "image/jpeg")) for p in NEGATIVES[:4]]
    for files, message in [
        (faces, "found in 0 of 4 photos"),
        ([photo(ROWS[0])], "found in 1 of 1 photos; 3 or more"),
        ([photo(ROWS[0])] * 2 + faces[:1], "found in 2 of 3 photos"),
        ([("image", ("x.jpg", b"not an image", "image/jpeg"))] * 3, "image 1 (x.jpg)"),
    ]:
        r = client.post("/v1/cameras", files=files)
        assert r.status_code in (400, 422) and message in r.json()["error"]["message"], r.text
    r = client.post("/v1/cameras", content=b"fx=900", headers={"content-type": "text/plain"})
    assert r.status_code == 415
    assert cameras(client) == before


def test_an_unknown_camera_is_a_404_everywhere(client: TestClient) -> None:
    for call in (client.get, client.delete):
        r = call("/v1/cameras/c-00000000")
        assert r.status_code == 404 and "GET /v1/cameras lists them" in r.json()["error"]["message"]
    r = client.post("/v1/models/default/predict?camera=nope", files=[photo(ROWS[0])])
    assert r.status_code == 404
    with client.websocket_connect("/v1/stream?camera=nope") as ws:
        assert ws.receive_json()["error"]["code"] == "camera_not_found"


def test_a_full_store_refuses_more_and_the_service_stays_healthy(
    app_factory: AppFactory, tmp_path: Path
) -> None:
    with app_factory(camera_db=tmp_path / "c.db", max_cameras=40) as c:
        for i in range(40):
            assert c.post("/v1/cameras", json={"fx": 500 + i}).status_code == 201
        r = c.post("/v1/cameras", json={"fx": 900})
        assert r.status_code == 409 and "POSE_MAX_CAMERAS" in r.json()["error"]["message"]
        assert len(cameras(c)) == 40
        assert c.get("/readyz").status_code == 200
        assert c.post("/v1/predict", files=[photo(ROWS[0])]).status_code == 200


def test_an_unusable_store_is_a_503_not_a_crash(app_factory: AppFactory, tmp_path: Path) -> None:
    blocked = tmp_path / "file"
    blocked.write_text("not a folder")
    with app_factory(camera_db=blocked / "c.db") as c:
        r = c.post("/v1/cameras", json={"fx": 900})
        assert r.status_code == 503 and r.json()["error"]["code"] == "camera_store_unavailable"
        assert c.post("/v1/predict", files=[photo(ROWS[0])]).status_code == 200


def test_the_stream_learns_its_camera_within_30_frames(client: TestClient) -> None:
    fx_true = float(ROWS[0]["fx"])
    with client.websocket_connect("/v1/stream") as ws:
        assert ws.receive_json()["learns_camera"] is True
        sources = []
        for row in ROWS:
            ws.send_bytes(photo(row)[1][1])
            answer = ws.receive_json()
            sources.append(answer["fx_source"])
    assert "stream" in sources[:30]
    first = sources.index("stream")
    assert all(s == "stream" for s in sources[first:])
    assert answer["fx"] == pytest.approx(fx_true, rel=0.10)
    assert answer["pose"]["fx_source"] == "stream"


def test_a_stream_with_a_stored_camera_uses_it(client: TestClient) -> None:
    camera = client.post("/v1/cameras", json={"fx": 1424.13, "width": 640, "height": 428}).json()
    with client.websocket_connect(f"/v1/stream?camera={camera['id']}&regions=8x3") as ws:
        hello = ws.receive_json()
        assert hello["camera"] == camera["id"] and hello["learns_camera"] is False
        ws.send_bytes(photo(ROWS[0])[1][1])
        answer = ws.receive_json()
    assert answer["fx_source"] == "camera" and answer["cell"]["grid"] == "8x3"
    with client.websocket_connect("/v1/stream?regions=banana") as ws:
        assert "expected AxE" in ws.receive_json()["error"]["message"]


#: Rows a store may hold that are no camera: JSON that does not parse, JSON that is no object,
#: fields that do not validate (a boolean, a principal point far outside the image), bytes
#: that are not UTF-8.
CORRUPT_ROWS: dict[str, str | bytes] = {
    "c-badjson1": '{"fx": 900, ',
    "c-notadict": "[1, 2]",
    "c-boolfx00": '{"fx": true, "source": "intrinsics"}',
    "c-hugecx00": '{"fx": 900, "cx": 1e300, "cy": 1, "width": 640, "height": 480, '
    '"source": "intrinsics"}',
    "c-notutf80": b"\xff\xfe{",
}


def put_rows(db: Path, rows: dict[str, str | bytes]) -> None:
    """Write rows into the store's table as they are (what a hand edit or a damaged file
    leaves)."""
    with closing(sqlite3.connect(db, isolation_level=None)) as con:
        for camera_id, body in rows.items():
            con.execute(
                "INSERT INTO cameras (id, created, body) VALUES (?, ?, ?)",
                (camera_id, "2026-01-01T00:00:00Z", body),
            )


@pytest.fixture
def store(client: TestClient, tmp_path: Path) -> Iterator[Path]:
    """The shared app with a store of its own in `tmp_path` for the test (its file's path)."""
    state = client.app.state.pose  # type: ignore[attr-defined]
    kept = state.cameras
    db = tmp_path / "c.db"
    state.cameras = CameraStore(db, 1000, state.metrics)
    try:
        yield db
    finally:
        state.cameras = kept


def test_a_corrupt_row_is_left_out_of_the_list_and_a_409_for_its_id_until_deleted(
    client: TestClient, store: Path, caplog: pytest.LogCaptureFixture
) -> None:
    c = client
    good = [c.post("/v1/cameras", json={"fx": 900.0 + i}).json()["id"] for i in range(2)]
    put_rows(store, CORRUPT_ROWS)
    assert sorted(k["id"] for k in cameras(c)) == sorted(good)
    assert cameras(c) and cameras(c)  # listed again: logged once per row all the same
    for camera_id in CORRUPT_ROWS:
        for r in (
            c.get(f"/v1/cameras/{camera_id}"),
            c.post(f"/v1/predict?camera={camera_id}", files=[photo(ROWS[0])]),
        ):
            error = r.json()["error"]
            assert r.status_code == 409 and error["code"] == "camera_corrupt", r.text
            assert f"DELETE /v1/cameras/{camera_id} clears it" in error["message"]
        with c.websocket_connect(f"/v1/stream?camera={camera_id}") as ws:
            assert ws.receive_json()["error"]["code"] == "camera_corrupt"
            with pytest.raises(WebSocketDisconnect) as closed:
                ws.receive_json()
        assert closed.value.code == 4409
        assert caplog.text.count(f"'{camera_id}' is stored corrupt") == 1, caplog.text
    metrics = c.get("/metrics").text
    for operation in ("list", "get", "predict", "stream"):
        assert f'pose_camera_corrupt_rows_total{{operation="{operation}"}}' in metrics
    for camera_id in CORRUPT_ROWS:
        assert c.delete(f"/v1/cameras/{camera_id}").status_code == 204
        assert c.get(f"/v1/cameras/{camera_id}").status_code == 404
    assert sorted(k["id"] for k in cameras(c)) == sorted(good)


def test_the_store_is_checked_at_start(
    app_factory: AppFactory, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """`PRAGMA quick_check` and every row read when the app starts, the outcome logged."""
    caplog.set_level(logging.INFO, "uvicorn.error.pose")
    db = tmp_path / "c.db"
    CameraStore(db, 10).create({"fx": 900.0, "source": "intrinsics"})
    put_rows(db, {"c-badjson1": "{"})
    no_models = tmp_path / "models"  # no model to load: the app starts at once
    no_models.mkdir()
    with app_factory(ready="/healthz", camera_db=db, model_dir=no_models) as c:
        assert len(cameras(c)) == 1
    assert "2 cameras, 1 unusable rows, integrity ok" in caplog.text, caplog.text
    assert "'c-badjson1' is stored corrupt" in caplog.text
    junk = tmp_path / "junk.db"
    junk.write_bytes(b"this is not a database" * 500)
    caplog.clear()
    with app_factory(ready="/healthz", camera_db=junk, model_dir=no_models) as c:
        r = c.get("/v1/cameras")
        assert r.status_code == 503 and "not an SQLite database" in r.json()["error"]["message"]
    assert "not an SQLite database" in caplog.text


def test_a_damaged_page_fails_the_integrity_check(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A page of the file overwritten: `check` (at start) logs it and counts it."""
    db = tmp_path / "c.db"
    store = CameraStore(db, 1000)
    for i in range(60):
        store.create({"fx": 500.0 + i, "source": "intrinsics", "name": "x" * 90})
    data = bytearray(db.read_bytes())
    page = 4096
    assert len(data) > 3 * page
    data[2 * page + 8 : 2 * page + 4000] = bytes(range(256)) * 15 + bytes(32)  # cells garbled
    db.write_bytes(bytes(data))
    metrics = Metrics()
    CameraStore(db, 1000, metrics).check_at_start()
    assert "the file is damaged: move it away or restore it" in caplog.text, caplog.text
    events = {"event": "integrity_failed"}
    assert metrics.registry.get_sample_value("pose_camera_store_events_total", events) == 1


@pytest.mark.parametrize("how", ["truncated", "replaced", "removed"])
def test_a_store_changed_under_the_service_is_logged(
    client: TestClient, store: Path, caplog: pytest.LogCaptureFixture, how: str
) -> None:
    metric = 'pose_camera_store_events_total{event="store_changed"}'

    def changes() -> float:
        line = [x for x in client.get("/metrics").text.splitlines() if x.startswith(metric)]
        return float(line[0].split()[-1]) if line else 0.0

    for i in range(20):
        assert client.post("/v1/cameras", json={"fx": 900.0 + i}).status_code == 201
    before = changes()
    if how == "truncated":
        store.write_bytes(b"")
    elif how == "replaced":
        other = store.with_name("other.db")
        CameraStore(other, 10).create({"fx": 700.0, "source": "intrinsics"})
        os.replace(other, store)
    else:
        store.unlink()
    caplog.clear()
    assert len(cameras(client)) == (1 if how == "replaced" else 0)
    assert f"camera store {store} was {how}" in caplog.text, caplog.text
    assert changes() == before + 1
    cameras(client)
    assert caplog.text.count(f"camera store {store} was") == 1  # once, not at every read


def test_the_sdk_takes_the_cameras_the_service_takes() -> None:
    """The SDK's CameraIntrinsics checks what CameraIn checks: same bounds, same verdicts."""
    for name in ("FX_BOUNDS_PX", "FY_OVER_FX", "DIST_LENGTHS", "DIST_NAMES", "TANGENTIAL_MAX"):
        assert getattr(sdk_models, name) == getattr(schemas, name), name
    assert (sdk_models.RADIAL_MAX, sdk_models.RATIONAL_MAX) == (
        schemas.RADIAL_MAX,
        schemas.RATIONAL_MAX,
    )
    size = {"width": 640, "height": 480}
    bodies: list[dict] = [
        {"fx": 900},
        {"fx": 900.5, "fy": 901, **size, "cx": 320, "cy": 240, "dist": [-0.3, 0.1, 0, 0, 0]},
        {"fx": 900, "dist": [20, -30, 0.01, 0, 5, 21, -29, 4]},
        {"fx": 900, "dist": [20, 0, 0, 0]},
        {"fx": 900, "dist": [0, 0, 0, 0, 0, 0, 0, 101]},
        {"fx": 900, "dist": [0, 0, 0.2, 0, 0]},
        {"fx": 900, "dist": [0, 0, 0, 0, 0, 0]},
        {"fx": 900, **size, "cx": 641, "cy": 0},
        {"fx": 900, **size, "cx": 0, "cy": 480.5},
        {"fx": 900, "cx": 3},
        {"fx": 900, "fy": 449},
        {"fx": 900, "fy": 1801},
        {"fx": True},
        {"fx": "900"},
        {"fx": 0.5},
        {"fx": 900, "width": 640},
        {"fx": 900, "width": 640.0, "height": 480},
        {"fx": 900, "lens": 1},
    ]
    taken = []
    for body in bodies:
        verdicts = []
        for model in (schemas.CameraIn, sdk_models.CameraIntrinsics):
            try:
                model.model_validate_json(json.dumps(body))
                verdicts.append(True)
            except ValidationError:
                verdicts.append(False)
        assert verdicts[0] == verdicts[1], (body, verdicts)
        taken.append(verdicts[0])
    assert taken == [True] * 3 + [False] * (len(bodies) - 3)
