"""The refinement at the photo's resolution (service/core/refine.py) on photos made from the
object's texture with a known homography and lens: where the corners are, through blur, a
hand over the object, the frame's edge, a far-off start, a half turn and a lens not known."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from service.core.paths import REPO_ROOT
from service.core.pose import Camera
from service.core.refine import (
    SELF_SIMILAR,
    CameraLens,
    RadialLens,
    Texture,
    extent,
    feature_start,
    homography_costs,
    refine_corners,
)

PROFILES = REPO_ROOT / "train/assets/profiles"
BACKGROUND = REPO_ROOT / "train/assets/backgrounds/photos/camera.jpg"
SIZE = (640, 360)  # (W, H) of the photos made here
#: Where the texture's corners land in the photo (a board seen obliquely, in object order).
TRUTH = np.array([[210.0, 300.0], [430.0, 285.0], [405.0, 60.0], [230.0, 75.0]])


def texture(name: str) -> Texture:
    bgr = cv2.imread(str(PROFILES / name / "texture.png"), cv2.IMREAD_COLOR)
    return Texture.of_rgb(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))


def background() -> np.ndarray:
    grey = cv2.imread(str(BACKGROUND), cv2.IMREAD_GRAYSCALE)
    return cv2.resize(grey, SIZE, interpolation=cv2.INTER_AREA)


def photo(tex: Texture, corners: np.ndarray = TRUTH) -> np.ndarray:
    """uint8 [H, W]: the texture warped onto the background with its corners at `corners`
    (pixel-edge corners of the texture -> the points given, as `Texture.corners`)."""
    up = cv2.resize(tex.grey, None, fx=4, fy=4, interpolation=cv2.INTER_LINEAR)
    src = (Texture(up).corners + 0.5) * 1.0 - 0.5
    H = cv2.getPerspectiveTransform(src.astype(np.float32), corners.astype(np.float32))
    board = cv2.warpPerspective(up, H, SIZE, flags=cv2.INTER_AREA)
    inside = cv2.warpPerspective(np.ones_like(up), H, SIZE, flags=cv2.INTER_AREA)
    out = inside * board + (1 - inside) * background().astype(np.float32) / 255.0
    return np.clip(out * 255.0 + 0.5, 0, 255).astype(np.uint8)


def through(lens_undistort, image: np.ndarray) -> np.ndarray:
    """The pinhole `image` as a lens shows it: each photo pixel samples the pinhole image
    where the lens's `undistort` sends it."""
    ys, xs = np.mgrid[0 : image.shape[0], 0 : image.shape[1]]
    flat = lens_undistort(np.column_stack([xs.ravel(), ys.ravel()]).astype(np.float64))
    mx = flat[:, 0].reshape(image.shape).astype(np.float32)
    my = flat[:, 1].reshape(image.shape).astype(np.float32)
    return cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def error(corners: np.ndarray, truth: np.ndarray = TRUTH) -> float:
    return float(np.linalg.norm(np.asarray(corners) - truth, axis=1).max())


START = TRUTH + np.array([[5.0, -4.0], [-6.0, 3.0], [4.0, 5.0], [-3.0, -6.0]])


@pytest.mark.parametrize(("name", "within"), [("charuco", 0.5), ("chessboard", 0.5), ("book", 1.0)])
def test_corners_a_few_px_off_are_brought_to_the_photos_pixels(name: str, within: float) -> None:
    """Up to 7 px off -> within half a px (a px for the book, a photo of soft edges)."""
    ref = refine_corners(photo(texture(name)), START, texture(name))
    assert ref.refined and ref.reason is None and not ref.turned
    assert error(ref.corners) < within < 5.0 < error(START)
    assert ref.score > 0.9 > ref.start_score
    assert np.array_equal(ref.corners, ref.pinhole)  # no lens


def test_a_half_turned_start_is_put_in_the_textures_order() -> None:
    """The chessboard turned by half a turn shows its squares' colours swapped: the texture
    correlates in one order only, the one the answer gives."""
    tex = texture("chessboard")
    ref = refine_corners(photo(tex), np.roll(START, 2, 0), tex)
    assert ref.refined and ref.turned
    assert error(ref.corners) < 0.5


def test_a_chessboard_start_a_square_off_is_tried_shifted() -> None:
    """A chessboard's start a square off along its width correlates weakly in both half-turn
    orders (a square's shift swaps the colours, as the half turn does); aligned from it
    alone, ECC locks onto the squares one square off. The shifted start that correlates best
    is aligned too, and the better alignment kept."""
    tex = texture("chessboard")
    square = (TRUTH[1] - TRUTH[0]) / 10.0  # the board is 10 squares wide
    ref = refine_corners(photo(tex), START + 0.8 * square, tex, features=False)
    assert ref.refined and error(ref.corners) < 0.5
    assert ref.start_score < 0.7 < 0.9 < ref.score


def test_only_a_self_similar_texture_is_tried_shifted() -> None:
    """The chessboard half turned and a square off is itself inside; the ChArUco board's
    markers and the book's picture are not: their weak starts are aligned once."""
    similarity = {name: texture(name).self_similarity for name in ("chessboard", "charuco", "book")}
    assert similarity["chessboard"] > 0.95
    assert max(similarity["charuco"], similarity["book"]) < SELF_SIMILAR < similarity["chessboard"]


def test_a_coarse_level_where_ecc_fails_is_skipped(monkeypatch: pytest.MonkeyPatch) -> None:
    """ECC fails at the pyramid's coarsest level (a chessboard's squares a few px wide can
    lose it): the finer levels align from the start, not the network's corners kept."""
    ecc, calls = cv2.findTransformECC, []

    def failing_first(*args: Any) -> Any:
        calls.append(args[0].shape)
        if len(calls) == 1:
            raise cv2.error("the correlation is going to be minimised")
        return ecc(*args)

    monkeypatch.setattr(cv2, "findTransformECC", failing_first)
    tex = texture("chessboard")
    ref = refine_corners(photo(tex), START, tex)
    assert len(calls) > 2 and calls[0][1] < calls[-1][1]  # the coarsest first, the finest last
    assert ref.refined and error(ref.corners) < 0.5


def test_a_coarse_level_that_moves_the_corners_too_far_ends_the_alignment(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """ECC at the coarsest level went far off (as on a photo without the object): the finer
    levels, which only refine where it went, are not run, and the start stands."""
    ecc, calls = cv2.findTransformECC, []

    def far_first(template: Any, image: Any, H0: Any, *rest: Any) -> Any:
        calls.append(image.shape)
        if len(calls) == 1:  # the level's width to the right
            shift = np.array([[1, 0, image.shape[1]], [0, 1, 0], [0, 0, 1]], np.float32)
            return 0.5, shift @ H0
        return ecc(template, image, H0, *rest)

    monkeypatch.setattr(cv2, "findTransformECC", far_first)
    tex = texture("charuco")
    ref = refine_corners(photo(tex), START, tex, features="off")
    assert len(calls) == 1
    assert not ref.refined and ref.reason == "the alignment moved the corners too far"
    assert np.array_equal(ref.corners, START)


def test_blur_a_hand_over_the_object_and_the_frames_edge_are_held() -> None:
    tex = texture("charuco")
    blurred = cv2.GaussianBlur(photo(tex), (0, 0), 2.5)
    assert error(refine_corners(blurred, START, tex).corners) < 1.0
    hand = photo(tex)
    cv2.ellipse(hand, (330, 170), (70, 45), 30, 0, 360, 150, -1)  # a skin-grey blob
    assert error(refine_corners(hand, START, tex).corners) < 0.5
    cut = TRUTH + [0.0, 90.0]  # its lower quarter below the photo
    ref = refine_corners(photo(tex, cut), cut + (START - TRUTH), tex)
    assert ref.refined and error(ref.corners, cut) < 0.5


def test_a_board_mostly_outside_the_photo_is_aligned_by_what_it_shows() -> None:
    """A board nearly 3x the photo's height, 20-40 % of it in view: the crop around it (the
    board and a margin) is mostly outside the photo, the part the photo shows is enough."""
    tex = texture("charuco")
    big = (TRUTH - TRUTH.mean(0)) * 4.0 + [420.0, 420.0]
    quad = np.zeros(SIZE[::-1], np.uint8)
    visible = cv2.fillPoly(quad, [np.round(big).astype(np.int32)], 1).sum()
    share = visible / cv2.contourArea(big.astype(np.float32))
    assert 0.2 < share < 0.4
    ref = refine_corners(photo(tex, big), big + 2.0 * (START - TRUTH), tex)
    assert ref.refined and error(ref.corners, big) < 4.0  # corners 500 px outside the photo


def test_a_heavily_blurred_photo_is_aligned_with_the_texture_blurred_alike() -> None:
    """Blurred by 4 px, the ChArUco board's fine markers mislead an alignment with the sharp
    texture (5.4 px off); with the texture blurred to the photo's blur it is within 2 px."""
    tex = texture("charuco")
    blurred = cv2.GaussianBlur(photo(tex), (0, 0), 4.0)
    ref = refine_corners(blurred, START, tex)
    assert ref.refined and error(ref.corners) < 2.0


def test_a_texture_with_large_plain_areas_aligns() -> None:
    """A plain sheet with a logo in one corner and a line of text: most of it gives ECC
    nothing to hold on to."""
    sheet = np.full((280, 200, 3), 235, np.uint8)
    cv2.circle(sheet, (45, 45), 25, (30, 60, 160), -1)
    cv2.putText(sheet, "planar pose", (20, 200), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (20, 20, 20), 2)
    tex = Texture.of_rgb(sheet)
    ref = refine_corners(photo(tex), START, tex)
    assert ref.refined and error(ref.corners) < 2.0


def test_a_start_far_off_is_found_by_the_textures_features() -> None:
    tex = texture("charuco")
    image = photo(tex)
    far = TRUTH + [180.0, 40.0]  # over the background, not the board
    found = feature_start(image, tex)
    assert found is not None and error(found) < 3.0
    ref = refine_corners(image, far, tex)
    assert ref.refined and error(ref.corners) < 0.5


def test_the_feature_search_looks_around_the_start_only() -> None:
    """Around corners that mark a region: found where the board lies in it, not where it lies
    outside (or the region is outside the photo); corners too close together mark no region
    (the whole photo is searched)."""
    tex = texture("charuco")
    image = photo(tex)
    found = feature_start(image, tex, TRUTH + [60.0, -30.0])
    assert found is not None and error(found) < 3.0
    left = np.array([[10.0, 200.0], [90.0, 200.0], [90.0, 120.0], [10.0, 120.0]])
    assert feature_start(image, tex, left) is None
    assert feature_start(image, tex, TRUTH + 5000.0) is None  # outside the photo
    tiny = feature_start(image, tex, left * 0.05 + 20)
    assert tiny is not None and error(tiny) < 3.0


def test_no_object_keeps_the_start_and_says_why() -> None:
    tex = texture("charuco")
    ref = refine_corners(background(), START, tex)
    assert not ref.refined and ref.reason is not None
    assert np.array_equal(ref.corners, START)
    tiny = refine_corners(background(), START * 0.02 + 100, tex)
    assert not tiny.refined and tiny.reason == "the object is too small to align"
    found = refine_corners(photo(tex), START * 0.02 + 100, tex)  # the features find it
    assert found.refined and error(found.corners) < 0.5


def test_a_time_budget_that_runs_out_keeps_the_start() -> None:
    tex = texture("charuco")
    ref = refine_corners(photo(tex), START, tex, budget_ms=1e-6)
    assert not ref.refined and ref.reason == "the alignment ran out of its time budget"
    assert np.array_equal(ref.corners, START)


@pytest.mark.parametrize("budget_ms", [2.0, 8.0, 20.0, 40.0])
def test_any_time_budget_ends_in_an_answer_with_a_lens_fit_running(budget_ms: float) -> None:
    """Wherever the budget runs out (the first alignment, the features, the lens fit), the
    answer is the start's or an alignment that held, never an error."""
    tex = texture("charuco")
    centre = ((SIZE[0] - 1) / 2, (SIZE[1] - 1) / 2)
    ref = refine_corners(photo(tex), START, tex, RadialLens(centre, 0.0), budget_ms, True)
    assert ref.refined or np.array_equal(ref.corners, START)
    assert ref.refined or ref.reason is not None


def test_a_known_lens_is_undone() -> None:
    """A webcam's barrel lens (OpenCV's coefficients): the corners as seen come back as the
    lens shows them, the pinhole ones as a pinhole would."""
    tex = texture("charuco")
    camera = Camera(330.0, SIZE, 328.0, 325.0, 185.0, (-0.3, 0.1, 0.001, -0.001, 0.0))
    lens = CameraLens(camera)
    image = through(lens.undistort, photo(tex))
    seen = lens.distort(TRUTH)
    ref = refine_corners(image, seen + (START - TRUTH), tex, lens)
    assert ref.refined
    assert error(ref.pinhole) < 0.5 and error(ref.corners, seen) < 0.5
    plain = refine_corners(image, seen + (START - TRUTH), tex)  # the lens ignored
    assert error(plain.corners, seen) > error(ref.corners, seen)


def test_a_radial_lens_not_known_is_fitted() -> None:
    tex = texture("charuco")
    centre = ((SIZE[0] - 1) / 2, (SIZE[1] - 1) / 2)
    unit = (SIZE[0] / 2) ** 2
    truth = RadialLens(centre, -0.25 / unit)
    image = through(truth.undistort, photo(tex))
    seen = truth.distort(TRUTH)
    ref = refine_corners(image, seen + (START - TRUTH), tex, RadialLens(centre, 0.0), fit_lens=True)
    assert ref.refined and isinstance(ref.lens, RadialLens)
    assert abs(ref.lens.kappa * unit + 0.25) < 0.1
    assert error(ref.pinhole) < 1.0 and error(ref.corners, seen) < 1.0
    plain = refine_corners(image, seen + (START - TRUTH), tex)  # no lens fitted
    assert error(plain.corners, seen) > 1.0


def test_radial_lens_maps_are_inverse_and_scale_with_the_image() -> None:
    lens = RadialLens((319.5, 179.5), -0.3 / 320**2)
    points = np.array([[0.0, 0.0], [639.0, 359.0], [319.5, 179.5], [100.0, 300.0]])
    assert np.allclose(lens.undistort(lens.distort(points)), points, atol=1e-6)
    fitted = RadialLens.fitted(lens.distort(points), points, lens.centre)
    assert fitted.kappa == pytest.approx(lens.kappa, rel=1e-6)
    half = lens.reduced(2.0)
    reduced = (points + 0.5) / 2.0 - 0.5
    assert np.allclose((half.distort(reduced) + 0.5) * 2.0 - 0.5, lens.distort(points))
    assert extent(TRUTH) == pytest.approx(np.linalg.norm(TRUTH[0] - TRUTH[2]))


def test_texture_files_the_models_carry_are_the_profiles(tmp_path: Path) -> None:
    """`Texture.corners` are the texture's pixel edges in the object's corner order:
    bottom-left, bottom-right, top-right, top-left."""
    tex = Texture(np.zeros((20, 30), np.float32))
    assert tex.corners.tolist() == [[-0.5, 19.5], [29.5, 19.5], [29.5, -0.5], [-0.5, -0.5]]


def test_homography_costs_are_the_least_squares_fits_residuals() -> None:
    """The grid's batched fit gives what OpenCV's least-squares homography leaves, per set."""
    rng = np.random.default_rng(0)
    uv = rng.random((40, 2))
    H = np.array([[800.0, 30.0, 100.0], [10.0, 700.0, 50.0], [0.1, 0.05, 1.0]])
    exact = cv2.perspectiveTransform(uv.reshape(-1, 1, 2), H).reshape(-1, 2)
    sets = np.stack([exact + rng.normal(0, s, exact.shape) for s in (0.0, 0.5, 2.0)])
    want = []
    for points in sets:
        fitted, _ = cv2.findHomography(uv, points, 0)
        back = cv2.perspectiveTransform(uv.reshape(-1, 1, 2), fitted).reshape(-1, 2)
        want.append(((back - points) ** 2).sum(1).mean())
    got = homography_costs(uv, sets)
    assert got.shape == (3,) and got[0] < 1e-12
    assert np.allclose(got[1:], want[1:], rtol=1e-2)
