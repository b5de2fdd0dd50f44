"""Rendering (SPEC 5): camera drawing, texture placement and colour parity, anti-aliased mask."""

from __future__ import annotations

import csv
from pathlib import Path

import cv2
import numpy as np
import pytest

from service.core.geometry import intrinsics, look_at, project_points, translation
from service.core.paths import ASSETS_DIR
from service.core.profile import load_profile
from service.core.regions import pose_class
from train.synth.background import BackgroundPool, procedural_backgrounds
from train.synth.render import Renderer, View, draw_views, occlude_edge, render_view

SIZE = (160, 120)


@pytest.fixture(scope="module")
def profile():
    return load_profile("chessboard")


def _square_centres() -> tuple[np.ndarray, np.ndarray]:
    """Centres (70, 3) cm of the 10 x 7 squares and their colour (True = black).

    Texture rule (train/assets/real/chessboard-stereo/README.md): the bottom-left square is black,
    colours alternate; column c from -x, row r from -y.
    """
    c, r = np.meshgrid(np.arange(10), np.arange(7))
    xyz = np.column_stack([(c.ravel() - 4.5) * 2.5, (r.ravel() - 3) * 2.5, np.zeros(70)])
    return xyz, (c.ravel() + r.ravel()) % 2 == 0


@pytest.mark.parametrize(
    "centre,roll,scale",
    [
        ((20, 20, 30), 0.0, 1.0),
        ((-25, 10, 45), 90.0, 0.7),
        ((-10, -30, 50), 180.0, 1.0),
        ((30, -5, 70), -45.0, 0.6),
        ((0.5, 0.5, 80), 30.0, 1.1),
    ],
)
def test_squares_land_where_the_geometry_projects_them(profile, centre, roll, scale):
    c = np.array(centre, float)
    image = render_view(profile, SIZE, c, roll_deg=roll, focal_scale=scale)
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(float)
    R = look_at(c, np.zeros(3), np.radians(roll))
    uv = project_points(intrinsics(SIZE, scale), R, translation(R, c), _square_centres()[0])
    black = _square_centres()[1]
    inside = (uv[:, 0] > 1) & (uv[:, 0] < SIZE[0] - 2) & (uv[:, 1] > 1) & (uv[:, 1] < SIZE[1] - 2)
    assert inside.sum() >= 10
    u, v = np.round(uv[inside]).astype(int).T
    values = grey[v, u]
    assert np.all(values[black[inside]] < 60) and np.all(values[~black[inside]] > 190)


def test_level_camera_on_plus_y_sees_top_edge_at_the_bottom(profile):
    # SPEC 5: a level camera on the +y side sees the object's top edge (y+) nearest, low in
    # the image; and world +x on its left.
    c = np.array([0.0, 30.0, 40.0])
    R = look_at(c, np.zeros(3))
    uv = project_points(intrinsics(SIZE), R, translation(R, c), [[0, 8, 0], [0, -8, 0], [10, 0, 0]])
    assert uv[0, 1] > uv[1, 1] and uv[2, 0] < SIZE[0] / 2


def test_mask_is_anti_aliased_and_has_the_right_area(profile):
    renderer = Renderer(
        profile,
        SIZE,
        jitter=False,
        backgrounds=BackgroundPool(SIZE, [np.zeros((120, 160, 3), np.uint8)]),
    )
    view = View(np.array([15.0, -20.0, 55.0]), np.zeros(3), 20.0, 1.0)
    board = renderer.boards[0]
    black = renderer.draw_object(np.zeros((120, 160, 3), np.uint8), view, board).astype(float)
    white = renderer.draw_object(np.full((120, 160, 3), 255, np.uint8), view, board).astype(float)
    alpha = 1.0 - (white - black).mean(axis=2) / 255.0
    assert alpha.min() >= -0.01 and alpha.max() <= 1.01
    edge = (alpha > 0.05) & (alpha < 0.95)
    assert edge.sum() > 40  # a soft edge all around, not a binary mask
    R = look_at(view.centre, view.target, np.radians(view.roll_deg))
    quad = project_points(intrinsics(SIZE), R, translation(R, view.centre), board.outline_cm)
    area = abs(cv2.contourArea(quad.astype(np.float32)))
    assert alpha.sum() == pytest.approx(area, rel=0.03)


@pytest.mark.parametrize("variant", ["C", "noC"])
def test_draw_views(profile, variant):
    rng = np.random.default_rng(1)
    classes = np.tile(np.arange(1, 9), 40)
    views = draw_views(profile, classes, variant, rng)
    centres = np.array([v.centre for v in views])
    targets = np.array([v.target for v in views])
    assert np.array_equal(pose_class(centres, profile.geometry.z_split_cm), classes)
    assert profile.geometry.contains(centres).all()
    if variant == "C":
        assert not targets.any()
    else:
        assert np.abs(targets[:, :2]).max() <= 3.0 and not targets[:, 2].any()
        assert np.abs(targets[:, :2]).max() > 2.0
    rolls = np.array([v.roll_deg for v in views])
    lo, hi = profile.roll_deg
    assert rolls.min() >= lo and rolls.max() <= hi and np.ptp(rolls) > 0.9 * (hi - lo)
    scales = np.array([v.focal_scale for v in views])
    assert scales.min() >= profile.focal_scale[0] and scales.max() <= profile.focal_scale[1]
    with pytest.raises(ValueError, match="variant"):
        draw_views(profile, classes, "X", rng)


def test_render_is_deterministic_and_class_zero_has_no_object(profile):
    renderer = Renderer(profile, (80, 60), jitter=True, seed=3)
    view = draw_views(profile, np.array([6]), "noC", np.random.default_rng(0))[0]
    a = renderer.render(view, 2, np.random.default_rng(5))
    b = renderer.render(view, 2, np.random.default_rng(5))
    assert a.shape == (60, 80, 3) and a.dtype == np.uint8 and np.array_equal(a, b)
    plain = Renderer(profile, (80, 60), jitter=False, backgrounds=renderer.backgrounds)
    background = plain.render(None, 0, np.random.default_rng(9))
    assert np.array_equal(background, plain.backgrounds.sample(np.random.default_rng(9)))


def test_real_photo_crops_avoid_the_board():
    from train.synth.background import board_polygon, real_photo_crops

    folder = ASSETS_DIR / "real" / "chessboard-stereo"
    crops = real_photo_crops(folder)
    assert len(crops) >= 10
    corners = {}
    with (folder / "labels.csv").open(newline="") as fh:
        for row in csv.DictReader(fh):
            corners[Path(row["file"]).stem] = np.array(
                [[float(row[f"corner_{a}{i}"]) for a in "xy"] for i in range(4)]
            )
    for name, rgb in crops:
        assert min(rgb.shape[:2]) >= 120 and rgb.dtype == np.uint8
        # the grown board polygon contains the inner corners (sanity of the DLT growth)
        polygon = board_polygon(corners[name.split("-")[0]], (20.0, 12.5), 6.0)
        inner = corners[name.split("-")[0]]
        for point in inner:
            assert cv2.pointPolygonTest(polygon.astype(np.float32), tuple(point), False) > 0


def test_background_pool_crops():
    sources = procedural_backgrounds(10, (100, 70), seed=1)
    assert all(s.shape == (70, 100, 3) and s.dtype == np.uint8 for s in sources)
    assert len({s.tobytes() for s in sources}) == 10
    pool = BackgroundPool((80, 60), sources)
    rng = np.random.default_rng(0)
    crops = [pool.sample(rng) for _ in range(20)]
    assert all(c.shape == (60, 80, 3) for c in crops)
    assert len({c.tobytes() for c in crops}) == 20


def test_an_occluder_needs_the_outline_and_draws_on_it() -> None:
    """A view with a corner behind the camera has no outline (two points: the frame's box),
    and gets no occluder instead of an IndexError; a real outline gets one on its edge."""
    image = np.zeros((120, 160, 3), np.uint8)
    occlude_edge(image, np.array([[0.0, 0.0], [160.0, 120.0]]), np.random.default_rng(0))
    assert not image.any()
    quad = np.array([[40.0, 90.0], [120.0, 90.0], [120.0, 30.0], [40.0, 30.0]])
    occlude_edge(image, quad, np.random.default_rng(0))
    assert image.any()
