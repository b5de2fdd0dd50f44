"""`/v1/cameras` (docs/pose.md): cameras from intrinsics or photos, kept in SQLite, used by
`?camera=`; hostile input gets a clear 4xx and stores nothing. The stream's learned camera."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient
from service_support import AppFactory
from test_service_pose import ROWS, photo

from service.core.paths import ASSETS_DIR

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
    "text", [b'{"fx":', b'{"fx": NaN}', b'{"fx": Infinity}', b"[]", b"\xff\xfe"]
)
def test_a_body_that_is_not_a_camera_is_a_422(client: TestClient, text: bytes) -> None:
    r = client.post("/v1/cameras", content=text, headers={"content-type": "application/json"})
    assert r.status_code == 422 and r.json()["error"]["code"] == "invalid_camera"


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
    with app_factory(camera_db=tmp_path / "c.db") as c:
        for i in range(1000):
            assert c.post("/v1/cameras", json={"fx": 500 + i}).status_code == 201
        r = c.post("/v1/cameras", json={"fx": 900})
        assert r.status_code == 409 and "POSE_MAX_CAMERAS" in r.json()["error"]["message"]
        assert len(cameras(c)) == 1000
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
