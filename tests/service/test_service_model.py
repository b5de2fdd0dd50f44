"""service.model: the shipped default model loads and follows the I/O contract; bad files fail."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
import pytest

from service.model import ModelLoadError, PoseModel
from service.settings import DEFAULT_MODEL


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
    assert PoseModel.load(path).name == "default"


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
    with pytest.raises(ModelLoadError, match="expected one output"):
        PoseModel.load(path)


def test_missing_and_garbage_files(tmp_path: Path) -> None:
    with pytest.raises(ModelLoadError, match="not found"):
        PoseModel.load(tmp_path / "none.onnx")
    (tmp_path / "junk.onnx").write_bytes(b"not onnx")
    with pytest.raises(ModelLoadError, match="not a loadable ONNX"):
        PoseModel.load(tmp_path / "junk.onnx")
