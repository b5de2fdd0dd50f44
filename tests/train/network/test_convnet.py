"""The convnet: shapes, the training-mode corner head, ONNX export, the corner loss."""

from __future__ import annotations

import numpy as np
import onnxruntime as ort
import pytest
import torch

from train.network.convnet import ConvNet
from train.network.export import onnx_bytes
from train.network.fit import _corner_loss
from train.network.model import build_network, export_form


@pytest.mark.parametrize("size", [(80, 60), (160, 120)])
def test_shapes_in_eval_and_training_mode(size):
    net = ConvNet(size)
    x = torch.rand(3, 3, size[1], size[0])
    net.train()
    logp, corners = net(x)
    assert logp.shape == (3, 9) and corners.shape == (3, 8)
    net.eval()
    out = net(x)
    assert out.shape == (3, 9)
    assert torch.allclose(out.exp().sum(1), torch.ones(3), atol=1e-5)


def test_unknown_size_and_architecture():
    with pytest.raises(ValueError, match="unsupported input size 64x48"):
        ConvNet((64, 48))
    with pytest.raises(ValueError, match="unknown architecture 'resnet'"):
        build_network("resnet", (160, 120))


def test_onnx_matches_torch_and_has_one_output():
    torch.manual_seed(0)
    net = build_network("convnet", (160, 120))
    net.train()
    for _ in range(2):  # move the batch-norm statistics off their defaults
        net(torch.rand(8, 3, 120, 160))
    net = export_form(net)
    session = ort.InferenceSession(onnx_bytes(net), providers=["CPUExecutionProvider"])
    assert [o.name for o in session.get_outputs()] == ["probabilities"]
    x = np.random.default_rng(0).random((5, 3, 120, 160), dtype=np.float32)
    got = session.run(None, {"image": x})[0]
    with torch.no_grad():
        want = torch.softmax(net.logits(torch.from_numpy(x)), 1).numpy()
    assert np.abs(got - want).max() < 1e-5


def test_corner_loss_ignores_unknown_corners():
    predicted = torch.zeros(3, 8, requires_grad=True)
    corners = np.full((3, 8), np.nan, np.float32)
    assert float(_corner_loss(predicted, corners, 160, 120).detach()) == 0.0
    corners[1] = [80, 60] * 4  # the image centre: 0 in [-1, 1] coordinates
    corners[2] = [160, 120] * 4  # the far corner: 1
    loss = _corner_loss(predicted, corners, 160, 120)
    loss.backward()
    assert float(loss.detach()) == pytest.approx((0.0 + (1.0 - 0.05)) / 2, abs=1e-3)
    assert predicted.grad is not None and float(predicted.grad[0].abs().sum()) == 0.0


def test_grid_pool_is_adaptive_average_pooling():
    from train.network.convnet import GridPool

    x = torch.rand(2, 5, 7, 10)
    want = torch.nn.AdaptiveAvgPool2d((3, 4))(x)
    assert torch.allclose(GridPool((7, 10), (3, 4))(x), want, atol=1e-6)


def test_corner_loss_takes_the_better_of_the_two_half_turns():
    corners = np.array([[10, 20, 150, 20, 150, 100, 10, 100]], np.float32)
    scale = np.tile([2 / 160, 2 / 120], 4)
    exact = torch.from_numpy((corners * scale - 1).astype(np.float32))
    turned = torch.roll(exact, 4, dims=1)  # (+X,+Y) first: the same board a half turn away
    quarter = torch.roll(exact, 2, dims=1)  # a quarter turn is a different board pose
    assert float(_corner_loss(exact, corners, 160, 120)) < 1e-9
    assert float(_corner_loss(turned, corners, 160, 120)) < 1e-9
    assert float(_corner_loss(quarter, corners, 160, 120)) > 0.5


def test_corner_loss_upper_order_takes_the_half_turn_with_corner_0_on_top():
    corners = np.array([[10, 100, 150, 100, 150, 20, 10, 20]], np.float32)  # corner 0 below 2
    scale = np.tile([2 / 160, 2 / 120], 4)
    exact = torch.from_numpy((corners * scale - 1).astype(np.float32))
    turned = torch.roll(exact, 4, dims=1)  # corner 2 (the upper one) first
    assert float(_corner_loss(turned, corners, 160, 120, order="upper")) < 1e-9
    assert float(_corner_loss(exact, corners, 160, 120, order="upper")) > 0.5
    assert float(_corner_loss(exact, corners, 160, 120, order="either")) < 1e-9
