"""The Open Inference Protocol (KServe v2) under /v2: tritonclient, the client a KServe/Triton
user has, against a live server with FP32 and BYTES inputs (JSON and binary tensors): images
get the same probabilities as /v1/predict (the whole pipeline: refinement, the pose's class),
a network input tensor the graph's own; the protocol's error cases in its error shape."""

from __future__ import annotations

import base64
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest
import tritonclient.http as triton
from fastapi.testclient import TestClient
from server_process import live_server
from service_support import CARD, OTHER_MODELS, REAL, SERVE, card_of
from tritonclient.utils import InferenceServerException

from service.core.paths import DEFAULT_MODEL, DEFAULT_MODEL_NAME
from service.core.preprocess import load_image, to_network_input
from service.pipeline.model import PoseModel
from service.pipeline.zoom import detail_decode_size

PHOTOS = [(REAL / name).read_bytes() for name in ("left01.jpg", "right05.jpg", "left12.jpg")]
SIZE = tuple(CARD["input"])  # the default model's (W, H)
VERSION = CARD["version"]
#: A shipped model with another input size than the default (for the shape error), if any.
OTHER = next((p for p in OTHER_MODELS if tuple(card_of(p)["input"]) != SIZE), OTHER_MODELS[0])
OTHER_SIZE = tuple(card_of(OTHER)["input"])


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    log = tmp_path_factory.mktemp("v2") / "serve.log"
    with live_server([*SERVE, "--workers", "1"], log) as (base, _):
        yield base


@pytest.fixture(scope="module")
def expected(server: str) -> np.ndarray:
    """/v1/predict's probabilities for PHOTOS (whole mode), [3, 9]."""
    files = [("image", (f"{i}.jpg", data, "image/jpeg")) for i, data in enumerate(PHOTOS)]
    r = httpx.post(server + "/v1/predict", files=files, timeout=60)
    assert r.status_code == 200, r.text
    return np.array([res["probabilities"] for res in r.json()["results"]])


@pytest.fixture()
def triton_client(server: str) -> Iterator[triton.InferenceServerClient]:
    c = triton.InferenceServerClient(url=server.removeprefix("http://"))
    yield c
    c.close()


def network_inputs(size: tuple[int, int]) -> np.ndarray:
    """PHOTOS preprocessed as the service does in whole mode (decoded with both sides at
    least twice the input height, for the zoom pass's detail): float32 [3, 3, H, W]."""
    decode = detail_decode_size(size)
    return np.stack([to_network_input(load_image(d, min_size=decode).rgb, size) for d in PHOTOS])


def test_health_and_metadata(triton_client: triton.InferenceServerClient) -> None:
    assert triton_client.is_server_live() and triton_client.is_server_ready()
    assert triton_client.is_model_ready("default") and not triton_client.is_model_ready("nope")
    server = triton_client.get_server_metadata()
    assert server["name"] == "planar-pose" and "binary_tensor_data" in server["extensions"]
    meta = triton_client.get_model_metadata("default")
    # the alias `default` answers with the name the default model is served under
    assert meta["name"] == DEFAULT_MODEL_NAME and meta["versions"] == [VERSION]
    assert {(i["name"], i["datatype"]) for i in meta["inputs"]} == {
        ("image", "FP32"),
        ("image_bytes", "BYTES"),
    }
    assert meta["inputs"][0]["shape"] == [-1, 3, SIZE[1], SIZE[0]]
    assert [(o["name"], o["datatype"], o["shape"]) for o in meta["outputs"]] == [
        ("probabilities", "FP32", [-1, 9]),
        ("class_id", "INT64", [-1]),
    ]


@pytest.mark.parametrize("binary", [True, False], ids=["binary", "json"])
def test_fp32_network_input_gives_the_graphs_probabilities(
    triton_client: triton.InferenceServerClient, binary: bool
) -> None:
    """A network input holds no photo to refine the corners in or pose from: the answer is
    the graph's own, as onnxruntime gives it."""
    tensor = network_inputs(SIZE)
    expected = PoseModel.load(DEFAULT_MODEL).predict(tensor)
    inp = triton.InferInput("image", list(tensor.shape), "FP32")
    inp.set_data_from_numpy(tensor, binary_data=binary)
    outputs = [triton.InferRequestedOutput(n, binary_data=False) for n in ("probabilities",)]
    result = triton_client.infer("default", [inp], outputs=None if binary else outputs)
    probs = result.as_numpy("probabilities")
    assert probs is not None and probs.shape == (3, 9) and probs.dtype == np.float32
    # the served graph may still run unoptimized (fused kernels differ by ~1e-5)
    assert np.abs(probs - expected).max() < 1e-4
    if binary:
        class_id = result.as_numpy("class_id")
        assert class_id is not None and class_id.dtype == np.int64
        assert class_id.tolist() == expected.argmax(axis=1).tolist()
    else:
        assert result.as_numpy("class_id") is None  # only what was asked for


@pytest.mark.parametrize("binary", [True, False], ids=["binary", "json-base64"])
def test_bytes_images_give_the_v1_probabilities(
    triton_client: triton.InferenceServerClient, expected: np.ndarray, binary: bool
) -> None:
    items = PHOTOS if binary else [base64.b64encode(d) for d in PHOTOS]
    data = np.array(items, dtype=np.object_)
    inp = triton.InferInput("image_bytes", [len(PHOTOS)], "BYTES")
    inp.set_data_from_numpy(data, binary_data=binary)
    result = triton_client.infer("default", [inp], request_id="req-7")
    assert result.get_response()["id"] == "req-7"
    assert result.get_response()["model_version"] == VERSION
    probs = result.as_numpy("probabilities")
    assert probs is not None and np.abs(probs - expected).max() < 1e-6
    assert result.as_numpy("class_id").tolist() == expected.argmax(axis=1).tolist()


def test_another_model_of_the_folder(triton_client: triton.InferenceServerClient) -> None:
    tensor = network_inputs(OTHER_SIZE)
    inp = triton.InferInput("image", list(tensor.shape), "FP32")
    inp.set_data_from_numpy(tensor)
    probs = triton_client.infer(OTHER.stem, [inp]).as_numpy("probabilities")
    assert probs is not None and probs.shape == (3, 9)
    assert np.allclose(probs.sum(axis=1), 1, atol=1e-5)


def test_protocol_errors_through_tritonclient(triton_client: triton.InferenceServerClient) -> None:
    tensor = network_inputs(SIZE)
    inp = triton.InferInput("image", list(tensor.shape), "FP32")
    inp.set_data_from_numpy(tensor)
    with pytest.raises(InferenceServerException, match="no model named 'nope'"):
        triton_client.infer("nope", [inp])
    if OTHER_SIZE != SIZE:
        w, h = OTHER_SIZE
        with pytest.raises(InferenceServerException, match=rf"shape must be \[N, 3, {h}, {w}\]"):
            triton_client.infer(OTHER.stem, [inp])
    with pytest.raises(InferenceServerException, match=f"version '{VERSION}', not '7'"):
        triton_client.infer("default", [inp], model_version="7")
    junk = triton.InferInput("image_bytes", [1], "BYTES")
    junk.set_data_from_numpy(np.array([b"not an image"], dtype=np.object_))
    with pytest.raises(InferenceServerException, match="image 1"):
        triton_client.infer("default", [junk])


ERRORS: dict[str, tuple[bytes | dict[str, object], int, str]] = {
    "not-json": (b"{nope", 400, "not JSON"),
    "no-inputs": ({"inputs": []}, 400, "exactly one tensor"),
    "int-datatype": (
        {"inputs": [{"name": "x", "datatype": "INT8", "shape": [1], "data": [1]}]},
        400,
        "FP32 or BYTES",
    ),
    "shape-vs-data": (
        {"inputs": [{"name": "x", "datatype": "FP32", "shape": [1, 3, 6, 8], "data": [0.5]}]},
        400,
        "1 values for shape [1, 3, 6, 8]",
    ),
    "bad-base64": (
        {"inputs": [{"name": "x", "datatype": "BYTES", "shape": [1], "data": ["%%%"]}]},
        400,
        "not valid base64",
    ),
    "unknown-output": (
        {
            "inputs": [{"name": "x", "datatype": "BYTES", "shape": [1], "data": ["AA=="]}],
            "outputs": [{"name": "logits"}],
        },
        400,
        "unknown output 'logits'",
    ),
    "too-many": (
        {"inputs": [{"name": "x", "datatype": "BYTES", "shape": [17], "data": ["AA=="] * 17}]},
        400,
        "batch of 17",
    ),
}


@pytest.mark.parametrize("name", list(ERRORS))
def test_error_cases_in_the_protocol_shape(client: TestClient, name: str) -> None:
    body, status, text = ERRORS[name]
    kwargs = {"content": body} if isinstance(body, bytes) else {"json": body}
    r = client.post("/v2/models/default/infer", **kwargs)  # type: ignore[arg-type]
    assert r.status_code == status, r.text
    assert set(r.json()) == {"error"} and isinstance(r.json()["error"], str)
    assert text in r.json()["error"], r.json()


def test_unknown_model_and_path_in_the_protocol_shape(client: TestClient) -> None:
    for path in ("/v2/models/nope", "/v2/models/nope/ready", "/v2/nothing-here"):
        r = client.get(path)
        assert r.status_code == 404 and isinstance(r.json()["error"], str), r.text
    assert "served: " in client.get("/v2/models/nope").json()["error"]


def test_v2_needs_the_api_key_but_health_stays_open(app_factory: object, tmp_path: Path) -> None:
    with app_factory(api_key="k2") as c:  # type: ignore[operator]
        r = c.get("/v2/models/default")
        assert r.status_code == 401 and isinstance(r.json()["error"], str)
        assert (
            c.get("/v2/models/default", headers={"authorization": "Bearer k2"}).status_code == 200
        )
        assert c.get("/v2/health/live").json() == {"live": True}
        assert c.get("/v2/health/ready").json() == {"ready": True}
