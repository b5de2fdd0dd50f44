"""The corner network: corners -> homography -> camera centre, parity, class probabilities,
training-mode outputs and the ONNX export of the whole decode."""

from __future__ import annotations

import math

import cv2
import numpy as np
import onnxruntime as ort
import pytest
import torch
from torch import nn

from service.core.blur import blur_image
from service.core.geometry import intrinsics, look_at, project_points, translation
from service.core.pose import FOCAL_PRIOR
from service.core.profile import load_profile
from service.core.regions import pose_class
from train.network import corners as corner_net
from train.network.align import TextureAlign, solve_spd, square_homography
from train.network.corners import CornerNet
from train.network.export import onnx_bytes
from train.network.fit import FitConfig, _grown, fit, load_network
from train.network.model import arch_of, build_network
from train.synth.generate import DatasetSpec, make_dataset

PROFILE = load_profile("chessboard")
HALF = np.array([PROFILE.width_cm / 2, PROFILE.height_cm / 2])
OBJECT_CORNERS = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]]) * [*HALF, 0]


def _view(
    net: CornerNet, centre: tuple[float, float, float], roll_deg: float, focal: float = 0.0
) -> np.ndarray:
    """Corners (4, 2) px of the board seen from `centre` (cm) by a camera of focal length
    `focal` px (default: 0.6 x the SPEC camera's) with the principal point at the image
    centre."""
    f = focal or 0.6 * float(intrinsics(net.size)[0, 0])
    (u0, v0) = net.principal.tolist()
    A = np.array([[f, 0, u0], [0, f, v0], [0, 0, 1.0]])
    R = look_at(np.array(centre), np.zeros(3), np.radians(roll_deg))
    return project_points(A, R, translation(R, np.array(centre)), OBJECT_CORNERS)


def _board_image(corners: np.ndarray, size: tuple[int, int] = (160, 120)) -> np.ndarray:
    """RGB uint8 [H, W, 3]: the profile's texture warped onto `corners` over mid grey."""
    texture = PROFILE.texture_rgb()
    th, tw = texture.shape[:2]
    src = np.float32([[0, th], [tw, th], [tw, 0], [0, 0]])  # (-X,-Y) is the bottom left
    H = cv2.getPerspectiveTransform(src, np.float32(corners))
    out = cv2.warpPerspective(texture, H, size, borderValue=(128, 128, 128))
    return np.ascontiguousarray(out)


def _input(image: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(image).permute(2, 0, 1)[None].float() / 255.0


@pytest.mark.parametrize(
    ("centre", "roll"), [((10.0, -15.0, 50.0), 30.0), ((-20.0, 12.0, 80.0), -150.0)]
)
def test_camera_centre_from_the_corners(centre, roll):
    net = CornerNet()
    net.self_calibrate.fill_(0.0)  # the prior camera, which the view is taken with
    q = torch.from_numpy(_view(net, centre, roll, float(net.focal))).float()[None]
    H = square_homography(q)
    unit = torch.tensor([[0.0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]])
    mapped = torch.einsum("ij,kj->ki", H[0], unit)
    assert torch.allclose(mapped[:, :2] / mapped[:, 2:], q[0], atol=1e-3)
    square = torch.ones(1)
    c = net.camera_centre(H, square)[0].double().numpy()
    assert np.abs(c - centre).max() < 0.05
    # the half-turned order is the same board seen from (-cx, -cy, cz)
    turned = square_homography(torch.roll(q, 2, 1))
    c_turned = net.camera_centre(turned, square)[0].double().numpy()
    assert np.abs(c_turned - np.array([-centre[0], -centre[1], centre[2]])).max() < 0.05


@pytest.mark.parametrize(("photo", "aspect"), [((1280, 720), 4 / 3), ((640, 640), 0.75)])
def test_camera_centre_of_a_photo_squashed_to_the_input_size(photo, aspect):
    """A 16:9 and a square photo resized to 160x120: the pixel aspect undoes the squash."""
    net = CornerNet()
    net.self_calibrate.fill_(0.0)
    centre = (12.0, -9.0, 55.0)
    w, h = photo
    f_photo = float(net.focal) * w / 160  # the prior camera, at the photo's scale
    A = np.array([[f_photo, 0, (w - 1) / 2], [0, f_photo, (h - 1) / 2], [0, 0, 1.0]])
    R = look_at(np.array(centre), np.zeros(3), np.radians(20.0))
    uv = project_points(A, R, translation(R, np.array(centre)), OBJECT_CORNERS)
    q = torch.from_numpy((uv + 0.5) * [160 / w, 120 / h] - 0.5).float()[None]
    assert aspect == pytest.approx((120 / h) / (160 / w))
    H = square_homography(q)
    c = net.camera_centre(H, torch.tensor([aspect]))[0].double().numpy()
    assert np.abs(c - centre).max() < 0.1
    squashed = net.camera_centre(H, torch.ones(1))[0].double().numpy()
    assert np.abs(squashed - centre).max() > 3.0


def _focal_estimate(net: CornerNet, q: torch.Tensor) -> float:
    return float(net.focal_length(net.centred_homography(square_homography(q), torch.ones(1)))[0])


def test_self_calibration_moves_the_focal_length_to_what_a_tilted_view_shows():
    net = CornerNet(focal_scale=0.6)
    f0 = float(net.focal)
    f_true = 0.72 * f0 / 0.6
    q = torch.from_numpy(_view(net, (30.0, -25.0, 40.0), 40.0, f_true)).float()[None]
    assert f0 + 0.5 * (f_true - f0) < _focal_estimate(net, q) < f_true
    net.self_calibrate.fill_(0.0)
    assert _focal_estimate(net, q) == pytest.approx(f0)


def test_a_known_focal_length_replaces_the_estimate_where_it_is_given():
    net = CornerNet(focal_scale=0.6)
    f0 = float(net.focal)
    q = torch.from_numpy(_view(net, (30.0, -25.0, 40.0), 40.0, 1.2 * f0)).float()
    Hc = net.centred_homography(square_homography(torch.stack([q, q])), torch.ones(2))
    estimate = net.focal_length(Hc)
    given = net.focal_length(Hc, torch.tensor([3.0 * f0, 0.0]))  # the second one unknown
    assert float(given[0]) == pytest.approx(3.0 * f0)  # outside the bounds: the caller's
    assert float(given[1]) == pytest.approx(float(estimate[1]))
    # a near-frontal view through a lens twice as long: the board is twice as far
    H = square_homography(torch.from_numpy(_view(net, (1.0, -0.5, 50.0), 30.0, f0)).float()[None])
    near = net.camera_centre(H, torch.ones(1), torch.tensor([f0]))
    far = net.camera_centre(H, torch.ones(1), torch.tensor([2 * f0]))
    assert float(near[0, 2]) == pytest.approx(50.0, rel=0.02)
    assert float(far[0, 2]) == pytest.approx(100.0, rel=0.02)


def test_a_near_frontal_view_keeps_the_prior_focal_length():
    net = CornerNet(focal_scale=0.6)
    f0 = float(net.focal)
    for f_true in (0.5 * f0 / 0.6, 0.9 * f0 / 0.6):  # the view says little about either
        q = torch.from_numpy(_view(net, (1.0, -0.5, 50.0), 30.0, f_true)).float()[None]
        assert abs(_focal_estimate(net, q) - f0) < 0.1 * f0


def test_a_strong_barrel_shortens_the_prior_focal_length():
    net = CornerNet()
    f0 = float(net.focal)
    q = torch.from_numpy(_view(net, (1.0, -0.5, 50.0), 30.0, f0)).float()[None].expand(3, 4, 2)
    Hc = net.centred_homography(square_homography(q), torch.ones(3))
    limit = corner_net.BARREL_LIMIT
    # a lens's own barrel at the prior focal length, then twice and three times as strong
    k1 = torch.tensor([0.5 * limit, 2 * limit, 3 * limit])
    f = net.focal_length(Hc, None, k1)  # a near-frontal view: the prior decides
    expected = [f0, f0 / math.sqrt(2), f0 / math.sqrt(3)]
    assert f.tolist() == pytest.approx(expected, rel=0.02)
    assert float(net.focal_length(Hc[:1])[0]) == pytest.approx(f0, rel=0.02)  # no lens fitted
    # the camera is closer by the same ratio: a barrel seen through a short lens
    near = net.camera_centre(square_homography(q), torch.ones(3), None, k1)[:, 2]
    assert (near[1:] / near[0]).tolist() == pytest.approx(
        [1 / math.sqrt(2), 1 / math.sqrt(3)], rel=0.03
    )


def test_parity_tells_the_half_turn():
    net = CornerNet()
    corners = _view(net, (12.0, 8.0, 45.0), 100.0)
    x = _input(_board_image(corners))
    q = torch.from_numpy(corners).float()[None]
    assert float(net.parity(x, square_homography(q))) > 0.8
    assert float(net.parity(x, square_homography(torch.roll(q, 2, 1)))) < -0.8
    flat = torch.full_like(x, 0.5)  # no board: no parity evidence either way
    assert abs(float(net.parity(flat, square_homography(q)))) < 0.05


def test_parity_blur_is_the_data_sets_level_3():
    """`blurred_checker`'s blur along each axis (its first kernel) is SPEC blur level 3 at
    160x120 as `blur_image` applies it: same taps, anchor and replicated borders."""
    net = CornerNet()
    rgb = np.random.default_rng(0).random((120, 160, 3)).astype(np.float32)
    want = blur_image(rgb, 3, 2)[..., 0]
    got = net.blur_v[0] @ torch.from_numpy(rgb[..., 0]) @ net.blur_u[0].T
    assert np.abs(got.numpy() - want).max() < 1e-5


@pytest.mark.parametrize("distance", [70.0, 80.0])
def test_parity_under_the_heaviest_blur(distance):
    """SPEC blur 3 (a nearly box-shaped 10 px kernel) inverts the checker of this board's
    3.8-4.4 px squares: the square centres alone, and the plain template the training step
    logs with (`blurred=False`), read the half turn; the blurred template reads it right."""
    net = CornerNet()
    corners = _view(net, (8.0, 6.0, distance), 170.0)
    x = _input(blur_image(_board_image(corners), 3, 2))
    q = torch.from_numpy(corners).float()[None]
    H = square_homography(q)
    centres = torch.cat([net.square_st, torch.ones(70, 1)], 1) @ H[0].T
    u, v = (centres[:, :2] / centres[:, 2:]).round().long().T
    grey = x[0].mean(0)[v, u]
    assert float(((grey - grey.mean()) * net.checker).sum()) < 0  # inverted at the centres
    assert float(net.parity(x, H, blurred=False)) < 0
    assert float(net.parity(x, H)) > 0.8
    assert float(net.parity(x, square_homography(torch.roll(q, 2, 1)))) < -0.8
    rendered = net.blurred_checker(H)[0, 0]
    board = rendered.abs() > 0.02
    corr = np.corrcoef(x[0].mean(0)[board].numpy(), rendered[board].numpy())[0, 1]
    assert corr > 0.85  # the render matches the data sets' blur of the board


def test_class_probabilities_follow_the_centre_and_the_parity():
    net = CornerNet()
    c = torch.tensor([[15.0, 10.0, 40.0], [-15.0, -10.0, 85.0], [0.0, 0.0, 60.0]])
    sure = net.class_probabilities(c, torch.ones(3))
    assert torch.allclose(sure.sum(1), torch.ones(3), atol=1e-6)
    assert sure.argmax(1)[:2].tolist() == [0, 6]  # classes 1 and 7
    assert torch.allclose(sure[2], torch.full((8,), 1 / 8), atol=1e-3)  # on every boundary
    turned = net.class_probabilities(c, torch.zeros(3))
    assert turned.argmax(1)[:2].tolist() == [2, 4]  # (-cx, -cy): classes 3 and 5
    assert pose_class(c[:2].numpy(), 60.0).tolist() == [1, 7]


class _FixedHeat(nn.Module):
    """Heat-map logits [N, 4, 120 / stride, 160 / stride] peaked at given corners, whatever
    the features."""

    def __init__(self, corners: np.ndarray, stride: int = 4) -> None:
        super().__init__()
        v, u = np.mgrid[0 : 120 // stride, 0 : 160 // stride] * stride + (stride - 1) / 2
        d2 = (u[None] - corners[:, :1, None]) ** 2 + (v[None] - corners[:, 1:, None]) ** 2
        self.register_buffer("maps", torch.from_numpy(-d2 / 8.0).float()[None])

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.maps.expand(x.shape[0], -1, -1, -1)


@pytest.mark.parametrize("stride", [4, 2])
def test_the_exported_graph_decodes_like_torch(stride):
    torch.manual_seed(0)
    net = CornerNet(stride=stride)
    corners = _view(net, (14.0, -9.0, 42.0), 25.0)
    net.heat = _FixedHeat(corners, stride)
    net.eval()
    x = _input(_board_image(corners)).repeat(3, 1, 1, 1).numpy()
    with torch.no_grad():
        want = net(torch.from_numpy(x)).exp().numpy()
        q = net.corners(torch.from_numpy(x)).numpy()
    # the peaks, aligned (with the lens fit, which the prior k1 of -0.2 draws a little away
    # from this undistorted image's 0)
    assert np.abs(q[0] - corners).max() < 0.6
    session = ort.InferenceSession(onnx_bytes(net), providers=["CPUExecutionProvider"])
    outputs = ["probabilities", "corners", "pattern", "undistorted"]
    assert [o.name for o in session.get_outputs()] == outputs
    got, got_corners, pattern, pinhole = session.run(None, {"image": x})
    with torch.no_grad():
        want_pinhole = net.answer(torch.from_numpy(x))[3].numpy()
    # the pose's corners: the lens's fitted distortion undone, a fraction of a pixel here
    assert np.abs(pinhole - want_pinhole).max() < 5e-3
    assert 0 < np.abs(pinhole - got_corners).max() < 2.0
    assert pattern.shape == (3,) and pattern.min() > 0.5  # the checker is found
    assert np.abs(got - want).max() < 1e-4
    # (float32 rounding of two runtimes, through the Gauss-Newton steps: 1.4e-3 px seen)
    assert got_corners.shape == (3, 4, 2) and np.abs(got_corners - q).max() < 5e-3
    assert got.shape == (3, 9) and np.allclose(got.sum(1), 1.0, atol=1e-5)
    present = got[0, 1:] / got[0, 1:].sum()
    assert int(present.argmax()) + 1 == 4  # near, x+, y-
    # `pixel_aspect`, `view` and `focal`: inputs with defaults (1; the whole frame; unknown)
    assert [i.name for i in session.get_inputs()] == ["image"]
    assert [i.name for i in session.get_overridable_initializers()] == [
        "pixel_aspect",
        "view",
        "focal",
    ]
    aspect = np.array([1.0, 4 / 3, 0.8], np.float32)
    fed = session.run(["probabilities"], {"image": x, "pixel_aspect": aspect})[0]
    assert np.abs(fed[0] - got[0]).max() < 1e-6 and np.abs(fed[1] - got[1]).max() > 1e-3
    with torch.no_grad():
        want_fed = net(torch.from_numpy(x), torch.from_numpy(aspect)).exp().numpy()
    # float32 rounding of two runtimes: 1.03e-4 seen on one machine; the aspect's effect is > 1e-3
    assert np.abs(fed - want_fed).max() < 3e-4
    # `view`: the same input read as the frame's tile at (40, 30) enlarged 2x; the corners
    # come back in frame pixels, the pose from them with the frame's camera
    view = np.tile(np.array([[40.0, 30.0, 0.5]], np.float32), (3, 1))
    tiled, tiled_corners, *_ = session.run(None, {"image": x, "view": view})
    origin = np.array([40.0, 30.0], np.float32)  # (u0, v0): x from u0, y from v0
    # (up to the lens fit, whose distortion is about the frame's centre, not the tile's)
    assert np.abs(tiled_corners - (origin + (got_corners + 0.5) * 0.5 - 0.5)).max() < 0.05
    assert np.abs(tiled - got).max() > 1e-3
    with torch.no_grad():
        log_p, want_corners, *_ = net.answer(torch.from_numpy(x), None, torch.from_numpy(view))
    assert np.abs(tiled - log_p.exp().numpy()).max() < 3e-4
    assert np.abs(tiled_corners - want_corners.numpy()).max() < 1e-3


def test_training_mode_outputs_and_build():
    profile = {"width_cm": 25, "height_cm": 17.5, "z_split_cm": 60, "focal_scale": [0.45, 0.8]}
    net = build_network("corners-coarse", (160, 120), profile=profile)
    assert arch_of(net) == "corners-coarse"
    net.train()
    logp, corners = net(torch.rand(2, 3, 120, 160))
    assert logp.shape == (2, 9) and corners.shape == (2, 8)
    assert torch.allclose(logp.exp().sum(1), torch.ones(2), atol=1e-5)
    (logp[:, 0].sum() + corners.sum()).backward()
    assert net.presence[-1].weight.grad is not None and net.heat.weight.grad is not None
    assert net.offset.weight.grad.abs().max() > 0  # the corners' offsets learn from zero
    with pytest.raises(ValueError, match="unsupported input size 80x60"):
        CornerNet((80, 60))
    with pytest.raises(ValueError, match="unsupported heat-map stride 3"):
        CornerNet(stride=3)
    with pytest.raises(ValueError, match="cannot read the profile's texture"):
        build_network("corners", (160, 120), profile=profile | {"texture": "none.png"})
    # the focal-length prior is the profile's (x the SPEC camera's), the project's without one
    spec_f = float(intrinsics((160, 120))[0, 0])
    assert float(net.focal) == pytest.approx(FOCAL_PRIOR * spec_f)
    longer = build_network("corners-coarse", (160, 120), profile=profile | {"focal_prior": 1.0})
    assert float(longer.focal) == pytest.approx(spec_f)


def test_stride_2_heat_maps_and_growing_from_a_stride_4_network():
    torch.manual_seed(0)
    parent = CornerNet()
    net = build_network("corners", (160, 120))
    assert arch_of(net) == "corners" and arch_of(parent) == "corners-coarse"
    x = torch.rand(2, 3, 120, 160)
    assert net._encode(x)[0].shape == (2, 4, 60, 80)
    grown = _grown(parent, net)
    ours, theirs = grown.state_dict(), parent.state_dict()
    shared = [k for k in theirs if k in ours and ours[k].shape == theirs[k].shape]
    assert all(torch.equal(ours[k], theirs[k]) for k in shared)
    assert {"heat.weight", "grid_u", "grid_v"} <= set(theirs) - set(shared)  # reshaped: fresh
    assert "up0.0.weight" in ours and "up0.0.weight" not in theirs


def test_fit_grows_a_stride_2_network_from_a_coarse_checkpoint(tmp_path):
    data = tmp_path / "tiny160"
    make_dataset(data, DatasetSpec("noC", 2, 0, 27, 4, PROFILE))
    base = {"epochs": 1, "batch_size": 8, "progress": False, "threads": 1, "optimizer": "adam"}
    fit(FitConfig(datasets=[data], out=tmp_path / "kp", arch="corners-coarse", **base))
    init = tmp_path / "kp" / "best.pt"
    fit(FitConfig(datasets=[data], out=tmp_path / "s2", arch="corners", init=init, **base))
    parent, _ = load_network(init)
    grown, checkpoint = load_network(tmp_path / "s2" / "last.pt")
    assert arch_of(grown) == "corners" and checkpoint["arch"] == "corners"
    assert checkpoint["parent"]["checkpoint"] == str(init)
    assert grown.heat.weight.shape == (4, 16, 1, 1)


def test_a_bfloat16_training_step_keeps_the_corners_and_the_geometry_in_float32():
    torch.manual_seed(0)
    net = build_network("corners", (160, 120)).train()
    x = torch.rand(4, 3, 120, 160)
    log_p, corners = net(x)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        log_p16, corners16 = net(x)
    assert log_p16.dtype == corners16.dtype == torch.float32
    assert (corners16 - corners).abs().max() < 0.01  # [-1, 1] units: under 0.8 px
    assert torch.isfinite(log_p16).all()


def test_solve_spd_matches_a_linear_solver():
    g = torch.Generator().manual_seed(0)
    J = torch.randn(6, 8, 200, generator=g) * torch.tensor([1, 1, 3, 3, 0.3, 0.3, 1, 1.0])[:, None]
    A, b = J @ J.transpose(1, 2), torch.randn(6, 8, generator=g)
    want = torch.linalg.solve(A.double(), b.double())
    assert ((solve_spd(A, b).double() - want).norm(dim=1) / want.norm(dim=1)).max() < 1e-4


@pytest.mark.parametrize("blur", [0.0, 1.5])
def test_alignment_moves_the_corners_onto_the_board(blur):
    net = CornerNet()
    corners = _view(net, (12.0, -8.0, 45.0), 35.0)
    image = _board_image(corners)
    if blur:
        image = cv2.GaussianBlur(image, (0, 0), blur)
    x = _input(image)
    off = torch.tensor([[1.8, -1.2], [-1.5, -1.6], [-1.0, 1.9], [1.7, 1.1]])
    q = torch.from_numpy(corners).float()[None] + off
    align = TextureAlign((160, 120))
    got, corr, _ = align(x, q)
    assert (got[0] - torch.from_numpy(corners).float()).norm(dim=1).max() < 0.4
    assert float(corr) > 0.7
    # the half-turned order aligns too, and its correlation tells the half turn
    got_turned, corr_turned, _ = align(x, torch.roll(q, 2, 1))
    assert torch.allclose(got_turned, torch.roll(got, 2, 1), atol=0.05)
    assert float(corr_turned) < -0.7


@pytest.mark.parametrize("k1", [-0.45, 0.0, 0.2])
def test_alignment_fits_the_lens_distortion(k1):
    """A board seen through a lens of radial distortion k1: the fit (started at the prior
    -0.2) finds k1, and its corners are where the image shows them."""
    net = CornerNet()
    corners = _view(net, (14.0, -10.0, 38.0), 20.0)
    lens = net.lens(torch.ones(1))
    # the image: every pixel shows the undistorted board where `Lens.undistort` sends it
    v, u = np.mgrid[0:120, 0:160].astype(np.float32)
    grid = torch.from_numpy(np.stack([u, v], -1))[None]
    source = lens.undistort(grid, torch.tensor(k1)).numpy()[0]
    image = cv2.remap(_board_image(corners), source[..., 0], source[..., 1], cv2.INTER_LINEAR)
    truth = lens.distort(torch.from_numpy(corners).float()[None], torch.tensor(k1))
    off = torch.tensor([[1.2, -0.8], [-1.0, -1.1], [-0.7, 1.3], [1.1, 0.8]])
    got, corr, fitted = net.align(_input(image), truth + off, lens)
    assert abs(float(fitted) - k1) < 0.1
    assert (got[0] - truth[0]).norm(dim=1).max() < 0.8 and float(corr) > 0.7


def test_alignment_gives_back_the_corners_without_a_board():
    q = torch.tensor([[[40.0, 30.0], [120.0, 32.0], [118.0, 90.0], [42.0, 88.0]]])
    got, corr, k1 = TextureAlign((160, 120))(torch.full((1, 3, 120, 160), 0.5), q)
    assert torch.equal(got, q) and abs(float(corr)) < 1e-3 and float(k1) == 0.0


def test_the_corners_come_in_the_object_order_whatever_the_heat_maps_say():
    net = CornerNet()
    corners = _view(net, (8.0, 11.0, 55.0), 150.0)
    net.heat = _FixedHeat(np.roll(corners, 2, 0))  # the heat maps' half turn
    net.eval()
    with torch.no_grad():
        got = net.corners(_input(_board_image(corners)))[0].numpy()
    assert np.abs(got - corners).max() < 0.5


def test_the_aligned_checker_pattern_is_evidence_of_the_board():
    net = CornerNet()
    corners = _view(net, (-10.0, 6.0, 50.0), -60.0)
    net.heat = _FixedHeat(corners)
    with torch.no_grad():  # a presence head that always says "not in view"
        net.presence[-1].weight.zero_()
        net.presence[-1].bias.fill_(-20.0)
    net.eval()
    with torch.no_grad():
        board = net(_input(_board_image(corners))).exp()[0]
        flat = net(torch.full((1, 3, 120, 160), 0.5)).exp()[0]
    assert float(board[0]) < 0.05 and float(flat[0]) > 0.99


def test_checkpoints_with_the_old_focal_bounds_still_load():
    net = CornerNet()
    state = net.state_dict()
    assert "focal_bounds" not in state  # derived from FOCAL_BOUNDS, not stored
    state["focal_bounds"] = torch.tensor([1.0, 2.0])  # as checkpoints before 3.3.0 have it
    CornerNet().load_state_dict(state)


def test_the_offsets_carry_a_corner_beyond_the_frame():
    net = CornerNet(stride=2)
    assert not net.offset.weight.any() and not net.offset.bias.any()  # zero to start with
    heat = torch.full((1, 4, 60, 80), -50.0)
    heat[0, :, 0, 0] = heat[0, :, 59, 79] = 50.0  # two cells, each half the mass
    offset = torch.zeros(1, 8, 60, 80)
    q = net._soft_argmax(heat, offset)
    assert torch.allclose(q[0], torch.tensor([(0.5 + 158.5) / 2, (0.5 + 118.5) / 2]).expand(4, 2))
    heat[0, :, 59, 79] = -50.0  # all the mass in the top left cell, centre (0.5, 0.5) px
    offset[0, 0:2] = torch.tensor([-12.0, -7.0])[:, None, None]  # corner 0 out of the frame
    q = net._soft_argmax(heat, offset)
    assert torch.allclose(q[0, 0], torch.tensor([-11.5, -6.5])) and (q[0, 1:] == 0.5).all()


def test_checkpoints_without_the_offsets_load_with_zero_offsets():
    state = {k: v for k, v in CornerNet().state_dict().items() if not k.startswith("offset.")}
    older = CornerNet()
    nn.init.ones_(older.offset.weight)
    older.load_state_dict(state)  # as the checkpoints before 3.9.0
    assert not older.offset.weight.any() and not older.offset.bias.any()


def _texture_view(texture: np.ndarray, q: np.ndarray) -> torch.Tensor:
    """The texture warped onto the corners q [4, 2] (CORNER_ORDER) of a 160x120 image."""
    h, w = texture.shape[:2]
    src = np.array([[0, h], [w, h], [w, 0], [0, 0]], np.float32) - 0.5
    M = cv2.getPerspectiveTransform(src, q.astype(np.float32))
    img = cv2.warpPerspective(texture, M, (160, 120), flags=cv2.INTER_AREA, borderValue=(0,) * 3)
    return torch.from_numpy(img).permute(2, 0, 1)[None].float() / 255


def test_a_textured_object_reads_its_half_turn_from_its_texture() -> None:
    """Any texture (`train.network.pattern`): the corners in the object's order correlate
    with it, the half-turned order anti-correlates; the chessboard stays the checker."""
    charuco = load_profile("charuco")
    net = build_network("corners", (160, 120), profile=charuco.manifest_entry()).eval()
    assert net.textured and net.templates.shape == (2, 9, 80)
    chess = build_network(
        "corners", (160, 120), profile=load_profile("chessboard").manifest_entry()
    )
    assert not chess.textured and chess.checker.shape == (70,)
    q = np.array([[50, 105], [112, 100], [108, 15], [55, 20]], np.float32)
    x = _texture_view(charuco.texture_rgb(), q)
    Q = torch.from_numpy(q)[None]
    assert float(net.parity(x, square_homography(Q))) > 0.5
    assert float(net.parity(x, square_homography(torch.roll(Q, 2, 1)))) < -0.5
    with torch.no_grad():
        logp, corners, *_ = net.answer(x)
    assert logp.shape == (1, 9) and corners.shape == (1, 4, 2)


def test_a_texture_aligns_from_either_half_turn_order() -> None:
    """A texture's half turn is no inversion the alignment's gain absorbs: corners given in
    the half-turned order align to the texture as well (returned in that order, with a
    negative correlation), not drift (`TextureAlign.forward`)."""
    charuco = load_profile("charuco")
    net = build_network("corners", (160, 120), profile=charuco.manifest_entry()).eval()
    q = np.array([[50, 105], [112, 100], [108, 15], [55, 20]], np.float32)
    x = _texture_view(charuco.texture_rgb(), q)
    off = torch.from_numpy(
        q + np.array([[1.5, -1.0], [-1.0, 1.5], [1.0, 1.0], [-1.5, -1.0]])
    ).float()
    with torch.no_grad():
        for start, sign in ((off[None], 1.0), (torch.roll(off, 2, 0)[None], -1.0)):
            aligned, corr, _ = net.align(x, start)
            back = aligned[0] if sign > 0 else torch.roll(aligned[0], 2, 0)
            assert np.abs(back.numpy() - q).max() < 1.5
            assert float(corr[0]) * sign > 0.5


def test_a_textured_network_exports_and_answers_like_torch() -> None:
    charuco = load_profile("charuco")
    net = build_network("corners", (160, 120), profile=charuco.manifest_entry()).eval()
    q = np.array([[50, 105], [112, 100], [108, 15], [55, 20]], np.float32)
    x = _texture_view(charuco.texture_rgb(), q)  # a clear view: no near-tie between grids
    # heat maps peaked 1 px off the corners, in the half-turned order: aligned back
    net.heat = _FixedHeat(np.roll(q, 2, 0) + 1.0, stride=2)
    session = ort.InferenceSession(onnx_bytes(net), providers=["CPUExecutionProvider"])
    got, corners = session.run(["probabilities", "corners"], {"image": x.numpy()})
    with torch.no_grad():
        want = net.logits(x).exp().numpy()
    assert np.abs(got - want).max() < 1e-3
    assert np.abs(corners[0] - q).max() < 1.5  # in the object's order
