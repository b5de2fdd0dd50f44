"""Many models per server: cards and graph sizes read from the file without a session, graphs
loaded on first use, the least recently used unloaded beyond POSE_MODEL_MEMORY_MB (never the
default), a graph that fails on first use answered 503 and reported, the cache's metrics, and
an app that starts serving with its default model loaded."""

from __future__ import annotations

import json
import logging
import shutil
import time
from pathlib import Path

import numpy as np
import onnx
import pytest
from fastapi.testclient import TestClient
from service_support import CARD, JPEG, PHOTO, AppFactory
from test_service_models import DEFAULT, SMALL, put

from service.app import create_app
from service.core.paths import DEFAULT_MODEL, DEFAULT_MODEL_DIR
from service.pipeline.model import ModelLoadError, PoseModel, read_card
from service.pipeline.model_cache import estimated_bytes
from service.pipeline.onnx_file import OnnxFileError, read_graph_size, read_metadata
from service.settings import Settings

SPEC_80x60 = DEFAULT_MODEL_DIR / "chessboard-spec-80x60.onnx"
SPEC_160x120 = DEFAULT_MODEL_DIR / "chessboard-spec-160x120.onnx"  # 21 nodes: optimized at once


def metric(c: TestClient, name: str) -> float:
    """The value of a series of /metrics, summed over its labels."""
    lines = c.get("/metrics").text.splitlines()
    return sum(
        float(ln.rsplit(" ", 1)[1]) for ln in lines if ln.split("{")[0].split(" ")[0] == name
    )


def loaded(c: TestClient) -> dict[str, bool]:
    return {m["name"]: m["loaded"] for m in c.get("/v1/models").json()["models"]}


def predict(c: TestClient, name: str) -> dict:
    r = c.post(f"/v1/models/{name}/predict", content=PHOTO, headers=JPEG)
    assert r.status_code == 200, r.text
    return r.json()


def test_card_and_graph_size_are_read_without_a_session() -> None:
    proto = onnx.load(str(DEFAULT_MODEL))
    assert read_metadata(DEFAULT_MODEL) == {p.key: p.value for p in proto.metadata_props}
    assert read_card(DEFAULT_MODEL) == json.loads(read_metadata(DEFAULT_MODEL)["model_card"])
    size = read_graph_size(DEFAULT_MODEL)
    weights = sum(t.ByteSize() for t in proto.graph.initializer)
    assert size.nodes == len(proto.graph.node) and size.initializer_bytes >= weights
    assert 15 * 2**20 < estimated_bytes(DEFAULT_MODEL) < 30 * 2**20  # ~20 MiB measured


@pytest.mark.parametrize(
    ("content", "reason"),
    [
        (b"not onnx", "wire type 6"),
        (DEFAULT_MODEL.read_bytes()[:100_000], "goes past the end"),
        (b"", "not an ONNX model"),
        (b"\x08\x07", "not an ONNX model"),  # an IR version and nothing else
        (b"\x08\xff\xff", "cut short"),
    ],
)
def test_files_that_are_not_onnx_are_refused_with_the_reason(
    tmp_path: Path, content: bytes, reason: str
) -> None:
    path = tmp_path / "m.onnx"
    path.write_bytes(content)
    with pytest.raises(OnnxFileError, match=reason):
        read_metadata(path)
    with pytest.raises(ModelLoadError, match="not a loadable ONNX model"):
        read_card(path)


def test_models_load_on_first_use_and_the_least_recent_go_beyond_the_budget(
    app_factory: AppFactory, tmp_path: Path
) -> None:
    for name in (DEFAULT, "a", "b"):
        put(tmp_path, name, SMALL)
    budget = 2.5 * estimated_bytes(SMALL) / 2**20  # the default and one more
    with app_factory(model_dir=tmp_path, model_memory_mb=budget) as c:
        assert loaded(c) == {DEFAULT: True, "a": False, "b": False}
        assert metric(c, "pose_model_loads_total") == 1  # the default, at start
        default = c.post("/v1/predict", content=PHOTO, headers=JPEG).json()
        first = predict(c, "a")
        assert first["results"][0]["probabilities"] == default["results"][0]["probabilities"]
        assert loaded(c) == {DEFAULT: True, "a": True, "b": False}
        predict(c, "a")
        assert (metric(c, "pose_model_cache_misses_total"), metric(c, "pose_models_loaded")) == (
            1,
            2,
        )
        predict(c, "b")  # over the budget: "a", the least recently used, goes
        assert loaded(c) == {DEFAULT: True, "a": False, "b": True}
        assert metric(c, "pose_model_cache_evictions_total") == 1
        predict(c, "a")  # loaded again; "b" goes, never the default
        assert loaded(c) == {DEFAULT: True, "a": True, "b": False}
        assert metric(c, "pose_model_loads_total") == 4
        assert metric(c, "pose_model_cache_hits_total") >= 2
        assert metric(c, "pose_model_loaded_bytes") == 2 * estimated_bytes(SMALL)


def _broken_graph(path: Path) -> None:
    """An ONNX file whose card reads but whose graph onnxruntime refuses (an unknown op)."""
    h = onnx.helper
    inp = h.make_tensor_value_info("image", onnx.TensorProto.FLOAT, ["N", 3, 120, 160])
    out = h.make_tensor_value_info("probabilities", onnx.TensorProto.FLOAT, ["N", 9])
    graph = h.make_graph([h.make_node("NoSuchOp", ["image"], ["probabilities"])], "g", [inp], [out])
    model = h.make_model(graph, opset_imports=[h.make_opsetid("", 17)])
    model.metadata_props.add(key="model_card", value=json.dumps({**CARD, "name": "broken"}))
    onnx.save(model, str(path))


def test_a_graph_that_fails_on_first_use_is_503_reported_and_not_tried_again(
    app_factory: AppFactory, tmp_path: Path
) -> None:
    put(tmp_path, DEFAULT, SMALL)
    _broken_graph(tmp_path / "broken.onnx")
    with app_factory(model_dir=tmp_path, api_key="k") as c:
        key = {"x-api-key": "k"}
        listed = c.get("/v1/models", headers=key).json()
        assert "broken" in [m["name"] for m in listed["models"]] and listed["problems"] == {}
        for _ in range(2):
            r = c.post("/v1/models/broken/predict", content=PHOTO, headers={**JPEG, **key})
            assert r.status_code == 503 and r.json()["error"]["code"] == "model_unavailable"
            message = r.json()["error"]["message"]
            assert "'broken' could not be loaded" in message and "broken.onnx" in message
        assert 'pose_model_loads_total{result="error"} 1.0' in c.get("/metrics").text
        problems = c.get("/v1/models", headers=key).json()["problems"]
        assert "not a loadable ONNX model" in problems["broken"]
        shutil.copyfile(SMALL, tmp_path / ".tmp.onnx")
        (tmp_path / ".tmp.onnx").replace(tmp_path / "broken.onnx")  # fixed, then reloaded
        assert c.post("/v1/models/reload", headers=key).json()["loaded"] == ["broken"]
        r = c.post("/v1/models/broken/predict", content=PHOTO, headers={**JPEG, **key})
        assert r.status_code == 200 and r.json()["model"] == "broken"  # the served name
        assert c.get("/v1/models", headers=key).json()["problems"] == {}


def test_the_app_serves_from_its_first_request_with_the_default_model_loaded() -> None:
    """The lifespan loads the default model before uvicorn accepts a connection: no request
    of a (re)started worker is answered 503 "model is loading"."""
    with TestClient(create_app(Settings())) as c:  # no waiting for /readyz
        assert c.get("/readyz").status_code == 200
        r = c.post("/v1/predict", content=PHOTO, headers=JPEG)
        assert r.status_code == 200 and np.isclose(sum(r.json()["results"][0]["probabilities"]), 1)


def test_the_optimized_graph_answers_as_the_onnx_file_and_a_damaged_one_is_replaced(
    tmp_path: Path,
) -> None:
    target = tmp_path / "default.ort"
    batch = np.random.default_rng(2).random((2, 3, 120, 160), dtype=np.float32)
    first = PoseModel.load(DEFAULT_MODEL, optimized=target)  # from ONNX, writes the graph
    assert target.is_file() and [p.name for p in tmp_path.iterdir()] == ["default.ort"]
    cached = PoseModel.load(DEFAULT_MODEL, optimized=target)
    want, got = first.run(batch), cached.run(batch)
    assert np.allclose(want.probabilities, got.probabilities, atol=1e-6)
    assert want.corners is not None and got.corners is not None
    assert np.allclose(want.corners, got.corners, atol=1e-4)
    assert cached.takes_focal and cached.card == first.card
    target.write_bytes(b"damaged")
    again = PoseModel.load(DEFAULT_MODEL, optimized=target)  # the ONNX file again
    assert np.allclose(again.run(batch).probabilities, want.probabilities, atol=1e-6)
    assert target.stat().st_size > 1000


def test_the_workers_write_one_optimized_graph_per_content(
    app_factory: AppFactory, tmp_path: Path
) -> None:
    folder, runtime = tmp_path / "models", tmp_path / "runtime"
    folder.mkdir()
    for name, source in ((DEFAULT, SPEC_160x120), ("copy", SPEC_160x120), ("small", SPEC_80x60)):
        put(folder, name, source)
    with app_factory(
        model_dir=folder, runtime_dir=runtime, workers=1, model_prepare=True, optimized_dir=None
    ) as c:
        optimized = runtime / "optimized"
        deadline = time.monotonic() + 60  # written in the background, at the lowest priority
        while len(list(optimized.glob("*.ort"))) < 2:
            assert time.monotonic() < deadline, list(optimized.iterdir())
            time.sleep(0.05)
        time.sleep(0.2)
        assert len(list(optimized.glob("*.ort"))) == 2  # the copy shares the default's
        assert predict(c, "small")["model"] == "small"  # the served name, its own graph


def test_a_cold_model_answers_unoptimized_at_once_then_runs_its_optimized_graph(
    app_factory: AppFactory, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """No optimized graph written yet (no background preparation): the graph loads as it is
    (a cold model's first answer within a second), is optimized in a thread meanwhile, and
    the optimized one takes its place, answering the same."""
    caplog.set_level(logging.INFO, logger="uvicorn.error.pose")
    folder, runtime = tmp_path / "models", tmp_path / "runtime"
    folder.mkdir()
    put(folder, DEFAULT, SPEC_80x60)  # optimized in milliseconds, even on a loaded machine
    with app_factory(
        model_dir=folder, runtime_dir=runtime, workers=1, model_prepare=False, optimized_dir=None
    ) as c:
        want = predict(c, DEFAULT)
        deadline = time.monotonic() + 60
        while "now runs its optimized graph" not in caplog.text:
            assert time.monotonic() < deadline, caplog.text
            time.sleep(0.05)
        assert f"model {DEFAULT} loaded unoptimized" in caplog.text
        assert len(list((runtime / "optimized").glob("*.ort"))) == 1
        got = predict(c, DEFAULT)
        assert got["results"][0]["class_id"] == want["results"][0]["class_id"]
        assert np.allclose(
            got["results"][0]["probabilities"], want["results"][0]["probabilities"], atol=1e-3
        )
