"""service.pipeline.model: the shipped default model loads and follows the I/O contract; bad
files fail."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import onnx
import pytest

from service.core.paths import DEFAULT_MODEL
from service.core.pose import FOCAL_PRIOR
from service.pipeline.model import ModelLoadError, PoseModel
from service.pipeline.predictor import Predictor
from service.settings import Settings


def test_default_model_contract() -> None:
    model = PoseModel.load(DEFAULT_MODEL)
    graph = onnx.load(str(DEFAULT_MODEL)).graph.input[0].type.tensor_type.shape.dim
    assert model.input_size == (graph[3].dim_value, graph[2].dim_value)
    assert model.card["name"] == model.name and list(model.card["input"]) == [*model.input_size]
    w, h = model.input_size
    probs = model.predict(np.random.default_rng(0).random((5, 3, h, w), dtype=np.float32))
    assert probs.shape == (5, 9) and np.allclose(probs.sum(axis=1), 1)


def _with_card(tmp_path: Path, card: dict | None) -> Path:
    proto = onnx.load(str(DEFAULT_MODEL))
    del proto.metadata_props[:]
    if card is not None:
        proto.metadata_props.add(key="model_card", value=json.dumps(card))
    path = tmp_path / "m.onnx"
    onnx.save(proto, str(path))
    return path


def test_card_from_sidecar_when_metadata_missing(tmp_path: Path) -> None:
    path = _with_card(tmp_path, None)
    with pytest.raises(ModelLoadError, match="no model_card"):
        PoseModel.load(path)
    path.with_suffix(".json").write_text(DEFAULT_MODEL.with_suffix(".json").read_text())
    assert PoseModel.load(path).name == DEFAULT_MODEL.stem


def test_card_and_graph_must_agree(tmp_path: Path) -> None:
    path = _with_card(tmp_path, {"name": "x", "input": [1, 2]})
    with pytest.raises(ModelLoadError, match="card says input"):
        PoseModel.load(path)


def test_wrong_output_rejected(tmp_path: Path) -> None:
    inp = onnx.helper.make_tensor_value_info("image", onnx.TensorProto.FLOAT, ["N", 3, 60, 80])
    out = onnx.helper.make_tensor_value_info("p", onnx.TensorProto.FLOAT, ["N", 3, 1, 1])
    node = onnx.helper.make_node("GlobalAveragePool", ["image"], ["p"])
    graph = onnx.helper.make_graph([node], "g", [inp], [out])
    path = tmp_path / "bad.onnx"
    onnx.save(onnx.helper.make_model(graph, opset_imports=[onnx.helper.make_opsetid("", 17)]), path)
    with pytest.raises(ModelLoadError, match="expected one output \\[N, 9\\]"):
        PoseModel.load(path)


def test_missing_and_garbage_files(tmp_path: Path) -> None:
    with pytest.raises(ModelLoadError, match="not found"):
        PoseModel.load(tmp_path / "none.onnx")
    (tmp_path / "junk.onnx").write_bytes(b"not onnx")
    with pytest.raises(ModelLoadError, match="not a loadable ONNX"):
        PoseModel.load(tmp_path / "junk.onnx")


def _two_output_model(tmp_path: Path, corners_shape: list) -> Path:
    """An 80x60 graph: probabilities [N, 9] (a constant softmax) and a `corners` output."""
    h = onnx.helper
    inp = h.make_tensor_value_info("image", onnx.TensorProto.FLOAT, ["N", 3, 60, 80])
    outs = [
        h.make_tensor_value_info("probabilities", onnx.TensorProto.FLOAT, ["N", 9]),
        h.make_tensor_value_info("corners", onnx.TensorProto.FLOAT, corners_shape),
    ]
    w9 = onnx.numpy_helper.from_array(np.ones((3, 9), np.float32), "w9")
    w8 = onnx.numpy_helper.from_array(np.ones((3, 8), np.float32), "w8")
    shape = onnx.numpy_helper.from_array(np.array(corners_shape[1:], np.int64), "shape")
    nodes = [
        h.make_node("GlobalAveragePool", ["image"], ["pooled"]),
        h.make_node("Flatten", ["pooled"], ["flat"]),
        h.make_node("MatMul", ["flat", "w9"], ["logits"]),
        h.make_node("Softmax", ["logits"], ["probabilities"]),
        h.make_node("MatMul", ["flat", "w8"], ["c8"]),
        h.make_node("Shape", ["image"], ["n"], end=1),
        h.make_node("Concat", ["n", "shape"], ["full"], axis=0),
        h.make_node("Reshape", ["c8", "full"], ["corners"]),
    ]
    graph = h.make_graph(nodes, "g", [inp], outs, [w9, w8, shape])
    path = tmp_path / "two.onnx"
    onnx.save(h.make_model(graph, opset_imports=[h.make_opsetid("", 17)]), path)
    path.with_suffix(".json").write_text(json.dumps({"name": "two", "input": [80, 60]}))
    return path


def test_a_corners_output_is_read_beside_the_probabilities(tmp_path: Path) -> None:
    model = PoseModel.load(_two_output_model(tmp_path, ["N", 4, 2]))
    assert model.corners_name == "corners"
    batch = np.random.default_rng(1).random((2, 3, 60, 80), dtype=np.float32)
    answer = model.run(batch)
    probs, corners = answer.probabilities, answer.corners
    assert answer.pattern is None and probs.shape == (2, 9) and np.allclose(probs.sum(axis=1), 1)
    assert corners is not None and corners.shape == (2, 4, 2)
    assert np.allclose(model.predict(batch), probs)


def test_a_corners_output_of_the_wrong_shape_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ModelLoadError, match="'corners' must be \\[N, 4, 2\\]"):
        PoseModel.load(_two_output_model(tmp_path, ["N", 2, 4]))


def test_models_without_corners_answer_none() -> None:
    model = PoseModel.load(DEFAULT_MODEL.with_name("chessboard-spec-160x120.onnx"))
    assert model.corners_name is None
    answer = model.run(np.zeros((1, 3, 120, 160), np.float32))
    assert answer.probabilities.shape == (1, 9) and answer.corners is None
    assert answer.pattern is None and not model.zooms


def _aspect_model(tmp_path: Path) -> Path:
    """An 80x60 graph whose class-0 logit is the `pixel_aspect` input (default [1]), the
    other logits 0: P(class 0) = e^a / (e^a + 8)."""
    h = onnx.helper
    inp = h.make_tensor_value_info("image", onnx.TensorProto.FLOAT, ["N", 3, 60, 80])
    aspect = h.make_tensor_value_info("pixel_aspect", onnx.TensorProto.FLOAT, ["A"])
    out = h.make_tensor_value_info("probabilities", onnx.TensorProto.FLOAT, ["N", 9])
    inits = [
        onnx.numpy_helper.from_array(np.zeros((3, 9), np.float32), "w9"),
        onnx.numpy_helper.from_array(np.eye(9, dtype=np.float32)[:1], "onehot"),
        onnx.numpy_helper.from_array(np.array([1], np.int64), "axis"),
        onnx.numpy_helper.from_array(np.ones(1, np.float32), "pixel_aspect"),  # the default
    ]
    nodes = [
        h.make_node("GlobalAveragePool", ["image"], ["pooled"]),
        h.make_node("Flatten", ["pooled"], ["flat"]),
        h.make_node("MatMul", ["flat", "w9"], ["zero"]),
        h.make_node("Unsqueeze", ["pixel_aspect", "axis"], ["a"]),
        h.make_node("Mul", ["a", "onehot"], ["bump"]),
        h.make_node("Add", ["zero", "bump"], ["logits"]),
        h.make_node("Softmax", ["logits"], ["probabilities"]),
    ]
    graph = h.make_graph(nodes, "g", [inp, aspect], [out], inits)
    path = tmp_path / "aspect.onnx"
    onnx.save(h.make_model(graph, opset_imports=[h.make_opsetid("", 17)]), path)
    path.with_suffix(".json").write_text(json.dumps({"name": "aspect", "input": [80, 60]}))
    return path


def test_the_pixel_aspect_reaches_a_model_that_takes_it(tmp_path: Path) -> None:
    model = PoseModel.load(_aspect_model(tmp_path))
    assert model.takes_aspect and [i.name for i in model.session.get_inputs()] == ["image"]

    def p0(a: float) -> float:
        return float(np.exp(a) / (np.exp(a) + 8))

    batch = np.zeros((2, 3, 60, 80), np.float32)
    assert np.allclose(model.predict(batch)[:, 0], p0(1.0))
    got = model.predict(batch, np.array([4 / 3, 0.75]))[:, 0]
    assert np.allclose(got, [p0(4 / 3), p0(0.75)])
    with pytest.raises(ValueError, match="3 values for 2 images"):
        model.predict(batch, np.ones(3))
    # whole mode: the upload's shape decides (16:9 -> 4/3; a portrait is turned first)
    predictor = Predictor(model, Settings())
    uploads = [(None, _png(w, h)) for w, h in ((1280, 720), (640, 480), (480, 640), (360, 640))]
    answers = [r.probabilities[0] for r in predictor.predict(uploads, "whole").results]
    assert np.allclose(answers, [p0(4 / 3), p0(1.0), p0(1.0), p0(4 / 3)], atol=1e-6)


def _png(w: int, h: int) -> bytes:
    ok, buf = cv2.imencode(".png", np.full((h, w, 3), 90, np.uint8))
    assert ok
    return buf.tobytes()


def test_the_focal_prior_is_the_cards_object_profiles(tmp_path: Path) -> None:
    card = json.loads(DEFAULT_MODEL.with_suffix(".json").read_text())
    assert PoseModel.load(DEFAULT_MODEL).focal_prior == card["camera_model"]["focal_prior_x_spec"]
    card["camera_model"]["focal_prior_x_spec"] = 1.0
    assert PoseModel.load(_with_card(tmp_path, card)).focal_prior == 1.0
    for unusable in (7.0, "long", None):  # outside the bounds, not a number: the project's
        card["camera_model"]["focal_prior_x_spec"] = unusable
        assert PoseModel.load(_with_card(tmp_path, card)).focal_prior == FOCAL_PRIOR
