"""The grid network: least-squares homography of the 88 square corners, point targets,
growing from a keypoint network (unit and through `fit`), and the ONNX export."""

from __future__ import annotations

import cv2
import numpy as np
import onnxruntime as ort
import pytest
import torch
from torch import nn

from train.network.export import onnx_bytes
from train.network.fit import FitConfig, _corner_loss, fit, load_network
from train.network.grid import POINTS, GridNet, fit_homography, solve_spd
from train.network.keypoint import KeypointNet
from train.network.model import arch_of, build_network
from train.profile import load_profile
from train.synth.generate import DatasetSpec, make_dataset

CORNERS = torch.tensor([[[20.0, 30.0], [130.0, 25.0], [140.0, 100.0], [15.0, 95.0]]])
UNIT = torch.tensor([[0.0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]])
K = POINTS[0] * POINTS[1]


def _corners_of(H: torch.Tensor) -> torch.Tensor:
    """Homographies [N, 3, 3] of the unit square -> its corners [N, 4, 2]."""
    p = torch.einsum("nij,kj->nki", H, UNIT)
    return p[..., :2] / p[..., 2:]


def test_solve_spd_matches_a_library_solver():
    g = torch.Generator().manual_seed(0)
    a = torch.randn(5, 8, 8, generator=g, dtype=torch.float64)
    M, b = a @ a.transpose(1, 2) + 0.1 * torch.eye(8), torch.randn(5, 8, generator=g)
    want = torch.linalg.solve(M, b.double())
    assert torch.allclose(solve_spd(M, b.double()), want, atol=1e-9)


def test_points_fit_the_homography_and_average_their_noise():
    net = GridNet()
    points = net.point_targets(CORNERS.reshape(1, 8)).reshape(1, K, 2)
    assert points.shape == (1, 88, 2)
    assert torch.allclose(points[0, [0, 10, 87, 77]], CORNERS[0], atol=1e-4)  # outer points
    exact = fit_homography(net.point_st, points, torch.ones(1, K))
    assert torch.allclose(_corners_of(exact), CORNERS, atol=1e-2)
    g = torch.Generator().manual_seed(1)
    noisy = points + torch.randn(200, K, 2, generator=g)  # 1 px per point
    H = fit_homography(net.point_st, noisy, torch.ones(200, K))
    err = (_corners_of(H) - CORNERS).norm(dim=2).mean()
    assert err < 0.6  # four corners read alone would be 1.25 px off on average
    ref, _ = cv2.findHomography(net.point_st.double().numpy(), noisy[0].double().numpy(), 0)
    ref_corners = cv2.perspectiveTransform(UNIT[None, :, :2].double().numpy(), ref)[0]
    assert np.abs(ref_corners - _corners_of(H)[0].double().numpy()).max() < 0.1


def test_weights_silence_an_outlier():
    net = GridNet()
    points = net.point_targets(CORNERS.reshape(1, 8)).reshape(1, K, 2).clone()
    points[0, 40] += 30.0
    weight = torch.ones(1, K)
    off = (_corners_of(fit_homography(net.point_st, points, weight)) - CORNERS).abs().max()
    weight[0, 40] = 1e-6
    on = (_corners_of(fit_homography(net.point_st, points, weight)) - CORNERS).abs().max()
    assert off > 1.0 and on < 1e-2


def test_a_half_turn_reverses_the_points():
    net = GridNet()
    points = net.point_targets(CORNERS.reshape(1, 8))
    turned = net.point_targets(torch.roll(CORNERS, 2, dims=1).reshape(1, 8))
    assert torch.allclose(turned.reshape(K, 2), points.reshape(K, 2).flip(0), atol=1e-3)


def test_corner_loss_trains_the_points_inside_the_image():
    net = GridNet()
    corners = np.array([[-30.0, 30, 130, 25, 140, 100, 15, 95]], np.float32)  # corner 0 out
    scaled = torch.from_numpy(corners * np.tile([2 / 160, 2 / 120], 4) - 1).float()
    target = net.point_targets(scaled)
    garbage = torch.where(target.abs() > 1, torch.full_like(target, 0.3), target)
    assert (target.abs() > 1).any()
    loss = {
        name: float(_corner_loss(pred, corners, 160, 120, order="upper", points=net.point_targets))
        for name, pred in (("garbage outside", garbage), ("all moved", target + 0.1))
    }
    assert loss["garbage outside"] < 1e-9 and loss["all moved"] > 0.04


def test_grown_from_a_keypoint_network_keeps_its_weights():
    torch.manual_seed(0)
    parent = KeypointNet()
    grid = build_network("grid", (160, 120))
    assert arch_of(grid) == "grid" and grid.heat.out_channels == K
    grid.grow_from(parent)
    ours, theirs = grid.state_dict(), parent.state_dict()
    assert all(torch.equal(ours[k], v) for k, v in theirs.items() if not k.startswith("heat."))
    assert torch.equal(grid.heat.weight[[0, 10, 87, 77]], parent.heat.weight)
    grid.train()
    logp, points = grid(torch.rand(2, 3, 120, 160))
    assert logp.shape == (2, 9) and points.shape == (2, 2 * K)


class _FixedHeat(nn.Module):
    """Heat-map logits [N, 88, 30, 40] peaked at given points, whatever the features."""

    def __init__(self, points: torch.Tensor) -> None:
        super().__init__()
        v, u = torch.meshgrid(torch.arange(30) * 4 + 1.5, torch.arange(40) * 4 + 1.5, indexing="ij")
        d2 = (u[None] - points[:, :1, None]) ** 2 + (v[None] - points[:, 1:, None]) ** 2
        self.register_buffer("maps", (-d2 / 8.0)[None])

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.maps.expand(x.shape[0], -1, -1, -1)


def test_the_exported_graph_decodes_like_torch():
    net = GridNet()
    net.heat = _FixedHeat(net.point_targets(CORNERS.reshape(1, 8)).reshape(K, 2))
    net.eval()
    x = torch.rand(3, 3, 120, 160)
    with torch.no_grad():
        want = net(x).exp().numpy()
        assert (net.corners(x)[0] - CORNERS[0]).abs().max() < 0.5
    session = ort.InferenceSession(onnx_bytes(net), providers=["CPUExecutionProvider"])
    got = session.run(None, {"image": x.numpy()})[0]
    assert got.shape == (3, 9) and np.abs(got - want).max() < 1e-4


@pytest.fixture(scope="module")
def tiny_160(tmp_path_factory):
    out = tmp_path_factory.mktemp("data") / "tiny160"
    make_dataset(out, DatasetSpec("noC", 2, 0, 45, 4, load_profile("chessboard")))
    return out


def test_fit_grows_a_grid_network_from_a_keypoint_checkpoint(tiny_160, tmp_path):
    base = {"epochs": 1, "batch_size": 8, "progress": False, "threads": 1, "optimizer": "adam"}
    fit(FitConfig(datasets=[tiny_160], out=tmp_path / "kp", arch="keypoint", **base))
    parent, _ = load_network(tmp_path / "kp" / "best.pt")
    fit(
        FitConfig(
            datasets=[tiny_160],
            out=tmp_path / "grid",
            arch="grid",
            init=tmp_path / "kp" / "best.pt",
            lr=0.0,
            **base,
        )
    )
    grown, checkpoint = load_network(tmp_path / "grid" / "last.pt")
    assert arch_of(grown) == "grid" and checkpoint["parent"]["checkpoint"].endswith("best.pt")
    params = dict(grown.named_parameters())
    assert torch.equal(params["heat.weight"][[0, 10, 87, 77]], parent.heat.weight)
    assert torch.equal(
        params["down3.0.0.weight"], dict(parent.named_parameters())["down3.0.0.weight"]
    )
