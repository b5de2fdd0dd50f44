"""The pose, the finer regions and a same-camera fit in the answers of `/v1/predict`
(docs/pose.md), on the corpus's real photos with their calibrated cameras."""

from __future__ import annotations

import csv

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient
from service_support import AppFactory

from service.core.inputs import spec_fx
from service.core.paths import ASSETS_DIR

SOURCE = ASSETS_DIR / "real/corpus/boards/a-pipi__python_stereo_camera_calibrate__left"
ROWS = list(csv.DictReader((SOURCE / "labels.csv").open(newline="", encoding="utf-8")))


def photo(row: dict[str, str]) -> tuple[str, tuple[str, bytes, str]]:
    return ("image", (row["file"], (SOURCE / row["file"]).read_bytes(), "image/jpeg"))


def centre(row: dict[str, str]) -> np.ndarray:
    return np.array([float(row[f"cam_{a}"]) for a in "xyz"])


def answer(client: TestClient, query: str, rows: list[dict[str, str]]) -> list[dict]:
    r = client.post(f"/v1/predict{query}", files=[photo(row) for row in rows])
    assert r.status_code == 200, r.text
    results: list[dict] = r.json()["results"]
    return results


def test_the_pose_with_the_true_focal_length_is_the_labelled_camera(client: TestClient) -> None:
    errors = []
    for row in ROWS[:6]:
        (result,) = answer(client, f"?fx={row['fx']}", [row])
        pose = result["pose"]
        assert pose["fx_source"] == "query" and pose["fx"] == pytest.approx(float(row["fx"]))
        assert pose["fx_range"] is None and pose["distance_range_cm"] is None
        errors.append(np.linalg.norm(np.array(pose["camera_cm"]) - centre(row)))
        assert pose["distance_cm"] == pytest.approx(np.linalg.norm(pose["camera_cm"]), abs=1e-2)
        assert result["image_size"] == [int(row["width"]), int(row["height"])]
    assert np.median(errors) / np.linalg.norm(centre(ROWS[0])) < 0.05


def test_an_estimated_focal_length_says_the_range_the_view_allows(client: TestClient) -> None:
    (result,) = answer(client, "", ROWS[:1])
    pose = result["pose"]
    assert pose["fx_source"] == "estimated" and result["fx_source"] is None
    lo, hi = pose["fx_range"]
    assert lo <= pose["fx"] <= hi
    near, far = pose["distance_range_cm"]
    assert near <= pose["distance_cm"] <= far
    assert near <= np.linalg.norm(centre(ROWS[0])) <= far  # the truth is among the answers


def test_the_pose_agrees_with_opencv_on_the_answered_corners(client: TestClient) -> None:
    """docs/pose.md's worked example: cv2.solvePnP on the answer's corners with the photo's
    calibration (its lens included) finds the camera the answer's pose found (which undid
    the lens the network fitted instead)."""
    for row in ROWS[2:5]:
        (result,) = answer(client, f"?fx={row['fx']}", [row])
        w, h = result["image_size"]
        fx = float(row["fx"])
        K = np.array([[fx, 0, (w - 1) / 2], [0, fx, (h - 1) / 2], [0, 0, 1]])
        dist = np.array([float(row[k]) for k in ("k1", "k2", "p1", "p2", "k3")])
        board = np.array([[-12.5, -8.75, 0], [12.5, -8.75, 0], [12.5, 8.75, 0], [-12.5, 8.75, 0]])
        corners = np.array(result["corners"])
        ok, rvec, tvec = cv2.solvePnP(board, corners, K, dist, flags=cv2.SOLVEPNP_IPPE)
        assert ok
        R, _ = cv2.Rodrigues(rvec)
        theirs, ours = -R.T @ tvec.ravel(), np.array(result["pose"]["camera_cm"])
        assert np.linalg.norm(theirs - ours) < 0.03 * np.linalg.norm(theirs)


def test_regions_name_the_cell_of_the_pose(client: TestClient) -> None:
    (result,) = answer(client, f"?fx={ROWS[3]['fx']}&regions=8x3x60", ROWS[3:4])
    cell, pose = result["cell"], result["pose"]
    assert cell["grid"] == "8x3x60" and 0 <= cell["index"] < 48
    lo, hi = cell["azimuth_deg"]
    assert lo <= pose["azimuth_deg"] < hi or lo <= pose["azimuth_deg"] - 360 < hi
    assert cell["elevation_deg"][0] <= pose["elevation_deg"] < cell["elevation_deg"][1]
    assert 0 < cell["probability"] <= 1
    assert sum(n["probability"] for n in cell["neighbours"]) <= 1 - cell["probability"] + 1e-3


@pytest.mark.parametrize(
    ("query", "message"),
    [
        ("?regions=8", "expected AxE"),
        ("?regions=%EF%BC%98x%EF%BC%93", "in ASCII digits"),  # full-width 8x3
        ("?regions=8x3x60,30", "increasing"),
        ("?fx=1000&camera=c-1", "give one of them"),
        ("?mode=sliding&fx=1000", "mode=whole only"),
        ("?same_camera=true&fx=900", "known already"),
    ],
)
def test_bad_pose_parameters_are_a_422(client: TestClient, query: str, message: str) -> None:
    r = client.post(f"/v1/predict{query}", files=[photo(ROWS[0])])
    assert r.status_code == 422 and message in r.json()["error"]["message"]


def test_same_camera_fits_one_focal_length_to_all_the_photos(client: TestClient) -> None:
    results = answer(client, "?same_camera=true", ROWS[:8])
    fxs = {r["pose"]["fx"] for r in results if r["pose"]}
    assert len(fxs) == 1
    (fx,) = fxs
    assert fx == pytest.approx(float(ROWS[0]["fx"]), rel=0.10)
    assert all(r["fx_source"] == "estimated" for r in results)
    r = client.post("/v1/predict?same_camera=true", files=[photo(ROWS[0])])
    assert r.status_code == 422 and "2 or more" in r.json()["error"]["message"]


def test_same_camera_turns_portraits_of_the_camera_back_first(client: TestClient) -> None:
    """Half of one camera's photos turned to portrait (the camera turned): the joint focal
    length is the one of the photos as they were taken."""
    rows = ROWS[:8]
    want = {r["pose"]["fx"] for r in answer(client, "?same_camera=true", rows) if r["pose"]}
    files = []
    for i, row in enumerate(rows):
        name, (filename, data, media) = photo(row)
        if i % 2:
            bgr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
            data = cv2.imencode(".png", cv2.rotate(bgr, cv2.ROTATE_90_CLOCKWISE))[1].tobytes()
            filename, media = filename + ".png", "image/png"
        files.append((name, (filename, data, media)))
    r = client.post("/v1/predict?same_camera=true", files=files)
    assert r.status_code == 200, r.text
    got = {res["pose"]["fx"] for res in r.json()["results"] if res["pose"]}
    assert len(want) == len(got) == 1
    assert got.pop() == pytest.approx(want.pop(), rel=0.02)


def test_a_model_without_corners_gives_no_pose(app_factory: AppFactory) -> None:
    from service.core.paths import DEFAULT_MODEL_DIR

    spec = DEFAULT_MODEL_DIR / "chessboard-spec-160x120.onnx"
    with app_factory(model_path=spec) as c:
        (result,) = answer(c, "", ROWS[:1])
    assert result["pose"] is None and result["corners"] is None


def test_a_head_on_view_keeps_its_models_own_focal_prior(client: TestClient) -> None:
    """The book's profile states the SPEC camera's focal length as its prior, the chessboard's
    model the project's 0.8 x: a photo that says nothing of its lens is posed near the book's
    (a head-on view's fit leans a little within the wide range it allows)."""
    book = cv2.imread(str(ASSETS_DIR / "profiles/book/texture.png"))
    frame = np.full((480, 640, 3), 128, np.uint8)
    h, w = 294, 210  # the profile's 15 x 21 cm exactly: a head-on view is a true rectangle
    frame[90 : 90 + h, 320 - w // 2 : 320 - w // 2 + w] = cv2.resize(book, (w, h))
    image = ("image", ("book.png", cv2.imencode(".png", frame)[1].tobytes(), "image/png"))
    r = client.post("/v1/predict?model=book-corners-160x120", files=[image])
    assert r.status_code == 200, r.text
    pose = r.json()["results"][0]["pose"]
    spec_f = float(spec_fx(640))
    lo, hi = pose["fx_range"]
    assert lo < spec_f < hi and pose["fx"] == pytest.approx(spec_f, rel=0.2)
    assert abs(pose["fx"] - spec_f) < abs(pose["fx"] - 0.8 * spec_f)
