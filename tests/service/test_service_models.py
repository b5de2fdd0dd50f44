"""The model folder in-process: every `<name>.onnx` served, chosen per request, listed with
its card; unknown names 404 with the known ones; reloads (behind the API key) pick up added,
replaced, broken and removed files, a request holding the old session finishing on it."""

from __future__ import annotations

import base64
import os
import shutil
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient
from service_support import CARD, JPEG, OTHER_MODELS, PHOTO, AppFactory, card_of, check_answer

from service.core.paths import DEFAULT_MODEL, DEFAULT_MODEL_NAME
from service.pipeline.model import training_of

DEFAULT = DEFAULT_MODEL_NAME
SMALL = DEFAULT_MODEL  # served as DEFAULT
LARGE = OTHER_MODELS[0]  # served as "board-large" (whatever its size)
REPLACEMENT = OTHER_MODELS[1]
KEY = {"x-api-key": "reload-key"}


def put(folder: Path, name: str, source: Path) -> None:
    """Copy a model and its card into `folder` as `name`, atomically (rename over)."""
    for suffix in (".json", ".onnx"):
        tmp = folder / f".{name}{suffix}.tmp"
        shutil.copyfile(source.with_suffix(suffix), tmp)
        os.replace(tmp, folder / f"{name}{suffix}")


@pytest.fixture()
def folder(tmp_path: Path) -> Path:
    put(tmp_path, DEFAULT, SMALL)
    put(tmp_path, "board-large", LARGE)
    return tmp_path


@pytest.fixture()
def served(app_factory: AppFactory, folder: Path) -> Iterator[TestClient]:
    with app_factory(model_dir=folder, api_key="reload-key") as c:
        yield c


def predict(c: TestClient, path: str = "/v1/predict") -> dict:
    r = c.post(path, content=PHOTO, headers={**JPEG, **KEY})
    assert r.status_code == 200, r.text
    return r.json()


def test_two_models_chosen_per_request(served: TestClient) -> None:
    small = predict(served, "/v1/models/default/predict")  # the alias of the default model
    large = predict(served, "/v1/models/board-large/predict")
    check_answer(small, "whole", [(640, 480)], model=DEFAULT)
    check_answer(large, "whole", [(640, 480)], model="board-large")  # served name, not card
    default = predict(served)  # /v1/predict answers with the default model
    assert default["model"] == DEFAULT
    assert default["results"][0]["probabilities"] == small["results"][0]["probabilities"]
    p_small, p_large = (np.array(a["results"][0]["probabilities"]) for a in (small, large))
    assert np.abs(p_small - p_large).max() > 1e-3  # really two networks
    sliding = served.post(
        "/v1/models/board-large/predict?mode=sliding", content=PHOTO, headers={**JPEG, **KEY}
    )
    check_answer(sliding.json(), "sliding", [(640, 480)], model="board-large")


def test_a_copied_model_answers_under_its_served_name_everywhere(
    app_factory: AppFactory, tmp_path: Path
) -> None:
    """models/foo.onnx copied from another model (its card's name that model's): every
    answer names it foo, the name it is served under; /v1/models keeps the card's name as
    card_name."""
    put(tmp_path, "foo", SMALL)
    put(tmp_path, "bar", LARGE)
    assert card_of(tmp_path / "foo.onnx")["name"] == DEFAULT
    with app_factory(model_dir=tmp_path, default_model="foo") as c:
        assert predict(c)["model"] == "foo"
        assert predict(c, "/v1/predict?model=bar")["model"] == "bar"
        assert predict(c, "/v1/models/default/predict")["model"] == "foo"
        assert predict(c, "/v1/models/bar/predict")["model"] == "bar"
        assert c.get("/readyz").json()["model"] == "foo"
        listed = {m["name"]: m for m in c.get("/v1/models").json()["models"]}
        assert set(listed) == {"foo", "bar"} and listed["foo"]["card_name"] == DEFAULT
        for query, name in (("", "foo"), ("?model=bar", "bar"), ("?model=default", "foo")):
            with c.websocket_connect(f"/v1/stream{query}") as ws:
                assert ws.receive_json()["model"] == name
        assert c.get("/v2/models/default").json()["name"] == "foo"
        assert c.get("/v2/models/bar/ready").json() == {"name": "bar", "ready": True}
        image = {"name": "image_bytes", "datatype": "BYTES", "shape": [1]}
        data = [base64.b64encode(PHOTO).decode()]
        for url, name in (("/v2/models/default/infer", "foo"), ("/v2/models/bar/infer", "bar")):
            r = c.post(url, json={"inputs": [{**image, "data": data}]})
            assert r.status_code == 200 and r.json()["model_name"] == name, r.text


def test_the_list_of_models(served: TestClient) -> None:
    body = served.get("/v1/models", headers=KEY).json()
    assert body["default"] == DEFAULT and body["problems"] == {}
    by_name = {m["name"]: m for m in body["models"]}
    assert set(by_name) == {DEFAULT, "board-large"}
    assert by_name["board-large"]["input"] == card_of(LARGE)["input"]
    assert not by_name["board-large"]["default"] and by_name[DEFAULT]["default"]
    assert by_name[DEFAULT]["profile"] == CARD["profile"]["name"]
    assert by_name[DEFAULT]["accuracy"] == CARD["accuracy"]
    assert served.get("/v1/models").status_code == 401


def test_unknown_model_is_404_with_the_known_names(served: TestClient) -> None:
    r = served.post("/v1/models/nope/predict", content=PHOTO, headers={**JPEG, **KEY})
    assert r.status_code == 404 and r.json()["error"]["code"] == "model_not_found"
    assert "'nope'" in r.json()["error"]["message"]
    assert f"served: board-large, {DEFAULT}" in r.json()["error"]["message"]


def test_reload_needs_the_key(served: TestClient) -> None:
    r = served.post("/v1/models/reload")
    assert r.status_code == 401 and r.json()["error"]["code"] == "unauthorized"


def test_reload_adds_replaces_refuses_and_removes(served: TestClient, folder: Path) -> None:
    first = predict(served)["results"][0]["probabilities"]
    predict(served, "/v1/models/board-large/predict")  # loaded: it outlives its file a while
    held = served.app.state.pose.predictor  # type: ignore[attr-defined]  # as a request holds it
    put(folder, "extra", SMALL)
    put(folder, DEFAULT, REPLACEMENT)
    (folder / "broken.onnx").write_bytes(b"not onnx")
    (folder / "board-large.onnx").unlink()
    report = served.post("/v1/models/reload", headers=KEY).json()
    # a vanished file's model answers for POSE_MODEL_GRACE_S more (an rm + cp deploy)
    assert report["models"] == ["board-large", DEFAULT, "extra"]
    assert sorted(report["loaded"]) == [DEFAULT, "extra"]
    assert report["removed"] == []
    assert "model file gone" in report["problems"]["board-large"]
    assert "not a loadable ONNX model" in report["problems"]["broken"]
    assert predict(served, "/v1/models/board-large/predict")["model"] == "board-large"
    assert predict(served)["model"] == DEFAULT  # the replacement's card names another
    assert predict(served, "/v1/models/extra/predict")["results"][0]["probabilities"] == first
    assert served.get("/v1/models", headers=KEY).json()["problems"] == report["problems"]
    # the old session still answers (what a request in flight at the swap does)
    old = held.predict([(None, PHOTO)], "whole").results[0].probabilities
    assert old == first
    # a broken replacement keeps the last good session of that name
    (folder / "extra.onnx").write_bytes(b"garbage")
    again = served.post("/v1/models/reload", headers=KEY).json()
    assert "extra" in again["models"] and "extra" in again["problems"]
    assert predict(served, "/v1/models/extra/predict")["results"][0]["probabilities"] == first
    unchanged = served.post("/v1/models/reload", headers=KEY).json()
    assert unchanged["loaded"] == [] and unchanged["removed"] == []


def test_a_vanished_file_is_served_for_its_grace_time_only(
    app_factory: AppFactory, folder: Path
) -> None:
    """POSE_MODEL_GRACE_S: the default model's file removed, it still answers (and /readyz
    says ready) until the grace time has passed; a file back within it is loaded."""
    with app_factory(model_dir=folder, model_grace_s=0.5, api_key="reload-key") as c:
        (folder / f"{DEFAULT}.onnx").unlink()
        report = c.post("/v1/models/reload", headers=KEY).json()
        assert DEFAULT in report["models"] and "model file gone" in report["problems"][DEFAULT]
        assert c.get("/readyz").status_code == 200 and predict(c)["model"] == DEFAULT
        time.sleep(0.6)
        report = c.post("/v1/models/reload", headers=KEY).json()
        assert report["removed"] == [DEFAULT] and DEFAULT not in report["problems"]
        assert c.get("/readyz").status_code == 503
        put(folder, DEFAULT, REPLACEMENT)  # a deploy that came too late
        assert c.post("/v1/models/reload", headers=KEY).json()["loaded"] == [DEFAULT]
        assert predict(c)["model"] == DEFAULT


def test_folder_without_a_default_is_not_ready(app_factory: AppFactory, tmp_path: Path) -> None:
    put(tmp_path, "only-this", SMALL)
    with app_factory(ready="/healthz", model_dir=tmp_path) as c:
        for _ in range(500):
            r = c.get("/readyz")
            if "loading" not in r.text:
                break
            time.sleep(0.01)
        assert r.status_code == 503
        assert f"no {DEFAULT}.onnx in" in r.json()["error"]["message"]
        assert "served: only-this" in r.json()["error"]["message"]
        assert predict(c, "/v1/models/only-this/predict")["model"] == "only-this"
        assert c.post("/v1/predict", content=PHOTO, headers=JPEG).status_code == 503


def test_the_folder_watcher_picks_up_a_new_file(app_factory: AppFactory, folder: Path) -> None:
    with app_factory(model_dir=folder, model_watch_s=0.05) as c:
        put(folder, "late", SMALL)
        for _ in range(400):
            if c.post("/v1/models/late/predict", content=PHOTO, headers=JPEG).status_code == 200:
                break
            time.sleep(0.02)
        else:
            pytest.fail("the watcher did not load late.onnx")


def test_a_models_picture_is_served_as_its_graph_carries_it(
    app_factory: AppFactory, folder: Path
) -> None:
    put(folder, "classifier", DEFAULT_MODEL.parent / "chessboard-spec-80x60.onnx")
    with app_factory(model_dir=folder, api_key="reload-key") as c:
        got = c.get(f"/v1/models/{DEFAULT}/texture", headers=KEY)
        assert got.status_code == 200 and got.headers["content-type"] == "image/png"
        picture = cv2.imdecode(np.frombuffer(got.content, np.uint8), cv2.IMREAD_COLOR)
        width, height = CARD["profile"]["width_cm"], CARD["profile"]["height_cm"]
        assert picture.shape[1] / picture.shape[0] == pytest.approx(width / height, rel=0.02)
        none = c.get("/v1/models/classifier/texture", headers=KEY)
        assert none.status_code == 404 and none.json()["error"]["code"] == "no_texture"
        unknown = c.get("/v1/models/nope/texture", headers=KEY)
        assert unknown.status_code == 404 and "served: " in unknown.json()["error"]["message"]
        assert c.get(f"/v1/models/{DEFAULT}/texture").status_code == 401
        listed = {
            m["name"]: m["training"] for m in c.get("/v1/models", headers=KEY).json()["models"]
        }
        assert listed == {DEFAULT: "trained", "board-large": "trained", "classifier": "trained"}


@pytest.mark.parametrize(
    ("card", "training"),
    [
        ({"architecture": "corners: ...", "zero_shot": {"presence_threshold": 0.4}}, "zero-shot"),
        ({"architecture": "corners-any: the generic corner network ..."}, "fine-tuned"),
        ({"architecture": "corners: train/network/corners.py ..."}, "trained"),
        ({}, "trained"),
    ],
)
def test_a_cards_training_names_how_the_model_knows_its_object(card: dict, training: str) -> None:
    assert training_of(card) == training
