"""A shipped corner model read back from its ONNX graph: fine-tuning without its
checkpoint."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnxruntime as ort
import pytest
import torch
from torch import nn

from service.core.paths import DEFAULT_MODEL, REPO_ROOT
from service.core.profile import load_profile
from train.network.fit import FitConfig, TrainingError, fit, load_network
from train.network.onnx_weights import (
    OnnxWeightsError,
    corner_net_from_onnx,
    recalibrate_batch_norm,
)
from train.synth.generate import DatasetSpec, make_dataset

DEFAULT = DEFAULT_MODEL


# a shipped graph of 3.4.0, before the corners' offsets (`CornerNet.offset`)
WITHOUT_OFFSETS = REPO_ROOT / "tests" / "fixtures" / "corners-3.4.0-no-offsets.onnx"


def _graph_probabilities(x: torch.Tensor, path: Path = DEFAULT) -> np.ndarray:
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    return session.run(["probabilities"], {"image": x.numpy()})[0]


def test_the_read_back_network_answers_like_the_graph_before_and_after_recalibration():
    x = torch.rand(6, 3, 120, 160, generator=torch.Generator().manual_seed(0))
    want = _graph_probabilities(x)
    net, parent = corner_net_from_onnx(DEFAULT)
    assert net.stride == 2 and parent["onnx"] == str(DEFAULT) and parent["data"]
    net.eval()
    with torch.no_grad():
        assert np.abs(net.logits(x).exp().numpy() - want).max() < 1e-3
    recalibrate_batch_norm(net, x)
    with torch.no_grad():
        assert np.abs(net.logits(x).exp().numpy() - want).max() < 1e-3
    # the convolutions' outputs now have unit variance on x, the batch norms their statistics
    norm = net.get_submodule("down2.1.1")
    assert isinstance(norm, nn.BatchNorm2d)
    assert torch.allclose(norm.running_var, torch.ones_like(norm.running_var), atol=1e-3)
    assert norm.running_mean.abs().max() > 0.01


def test_a_graph_without_the_offsets_reads_back_with_zero_offsets():
    x = torch.rand(4, 3, 120, 160, generator=torch.Generator().manual_seed(2))
    net, _ = corner_net_from_onnx(WITHOUT_OFFSETS)
    assert not net.offset.weight.any() and not net.offset.bias.any()
    with torch.no_grad():
        got = net.eval().logits(x).exp().numpy()
    assert np.abs(got - _graph_probabilities(x, WITHOUT_OFFSETS)).max() < 1e-3


def test_fine_tuning_from_the_graph_at_learning_rate_0_keeps_its_answers(tmp_path):
    data = tmp_path / "tiny160"
    make_dataset(data, DatasetSpec("free", 2, 0, 27, 4, load_profile("chessboard")))
    config = FitConfig(
        datasets=[data], out=tmp_path / "ft", init=DEFAULT, epochs=1, batch_size=8, lr=0.0,
        optimizer="adam", weight_decay=0.0, progress=False, threads=1,
    )  # fmt: skip
    fit(config)
    tuned, checkpoint = load_network(tmp_path / "ft" / "last.pt")
    assert checkpoint["parent"]["checkpoint"] == str(DEFAULT)
    x = torch.rand(4, 3, 120, 160, generator=torch.Generator().manual_seed(1))
    tuned.eval()
    with torch.no_grad():  # only the running statistics moved (one epoch, momentum 0.1)
        assert np.abs(tuned.logits(x).exp().numpy() - _graph_probabilities(x)).max() < 0.05


def test_what_is_not_a_corner_graph_is_refused(tmp_path):
    with pytest.raises(OnnxWeightsError, match="not a planar-pose corner network"):
        corner_net_from_onnx(REPO_ROOT / "models" / "chessboard-spec-80x60.onnx")
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"not a model")
    with pytest.raises(OnnxWeightsError, match="not a readable ONNX model"):
        corner_net_from_onnx(junk)
    with pytest.raises(OnnxWeightsError, match="ONNX model not found"):
        corner_net_from_onnx(tmp_path / "missing.onnx")
    small = tmp_path / "tiny80"
    make_dataset(small, DatasetSpec("noC", 1, 0, 18, 4, load_profile("chessboard")))
    for init, message in ((junk, "not a readable ONNX model"), (DEFAULT, "takes 160x120 images")):
        config = FitConfig(datasets=[small], out=tmp_path / "run", init=init, progress=False)
        with pytest.raises(TrainingError, match=message):
            fit(config)
