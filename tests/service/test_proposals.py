"""Object proposals (objectness mode): boxes inside the image, of the network's aspect,
without duplicates, deterministic, and one of them around a pasted object."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from service_support import REAL as TEXTURE

from service.pipeline.proposals import fit_aspect, propose_boxes


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    x0, y0 = max(a[0], b[0]), max(a[1], b[1])
    x1, y1 = min(a[0] + a[2], b[0] + b[2]), min(a[1] + a[3], b[1] + b[3])
    inter = max(0, x1 - x0) * max(0, y1 - y0)
    return inter / (a[2] * a[3] + b[2] * b[3] - inter)


def _scene(seed: int, at: tuple[int, int], size=(640, 480)) -> np.ndarray:
    """A smooth random background with the chessboard texture pasted at `at` (x, y)."""
    rng = np.random.default_rng(seed)
    noise = rng.integers(0, 256, (size[1], size[0], 3), dtype=np.uint8)
    image = cv2.GaussianBlur(noise, (0, 0), 8)
    texture = cv2.cvtColor(cv2.imread(str(TEXTURE / "texture.png")), cv2.COLOR_BGR2RGB)
    x, y = at
    image[y : y + texture.shape[0], x : x + texture.shape[1]] = texture
    return image


@pytest.fixture(scope="module")
def photo() -> np.ndarray:
    bgr = cv2.imread(str(TEXTURE / "left03.jpg"))
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


@pytest.mark.parametrize("aspect", [4 / 3, 1.0, 0.5])
def test_boxes_are_inside_and_of_the_aspect(photo, aspect):
    boxes = propose_boxes(photo, aspect, 30)
    h, w = photo.shape[:2]
    assert boxes.dtype.kind == "i" and boxes.ndim == 2 and boxes.shape[1] == 4
    assert 1 <= len(boxes) <= 30
    assert np.all(boxes[:, :2] >= 0) and np.all(boxes[:, 2:] >= 1)
    assert np.all(boxes[:, 0] + boxes[:, 2] <= w) and np.all(boxes[:, 1] + boxes[:, 3] <= h)
    # Rounding to whole pixels moves the aspect by at most one pixel on either side.
    ratio = boxes[:, 2] / boxes[:, 3]
    assert np.all(np.abs(ratio - aspect) <= aspect * (1.5 / boxes[:, 3] + 1.5 / boxes[:, 2]))


def test_no_duplicates_and_cap(photo):
    boxes = propose_boxes(photo, 4 / 3, 5)
    assert len(boxes) <= 5
    for i in range(len(boxes)):
        for j in range(i + 1, len(boxes)):
            assert _iou(boxes[i], boxes[j]) <= 0.6 + 1e-9


def test_deterministic(photo):
    assert np.array_equal(propose_boxes(photo, 4 / 3, 20), propose_boxes(photo, 4 / 3, 20))


@pytest.mark.parametrize("seed, at", [(0, (380, 250)), (1, (40, 60)), (2, (220, 170))])
def test_a_box_covers_a_pasted_object(seed, at):
    image = _scene(seed, at)
    boxes = propose_boxes(image, 4 / 3, 20)
    target = fit_aspect(np.array([[at[0], at[1], 200, 140]]), 4 / 3, (640, 480), 0.0)[0]
    assert max(_iou(b, target) for b in boxes) >= 0.6


def test_small_and_odd_images():
    tiny = np.zeros((10, 7, 3), np.uint8)
    boxes = propose_boxes(tiny, 4 / 3, 3)
    assert len(boxes) >= 1
    assert np.all(boxes[:, 0] + boxes[:, 2] <= 7) and np.all(boxes[:, 1] + boxes[:, 3] <= 10)


@pytest.mark.parametrize(
    "image, aspect, n",
    [
        (np.zeros((20, 20), np.uint8), 1.0, 3),
        (np.zeros((20, 20, 3), np.float32), 1.0, 3),
        (np.zeros((20, 20, 3), np.uint8), 0.0, 3),
        (np.zeros((20, 20, 3), np.uint8), 1.0, 0),
    ],
)
def test_bad_input(image, aspect, n):
    with pytest.raises(ValueError):
        propose_boxes(image, aspect, n)


def test_fit_aspect_keeps_centre_when_room():
    box = fit_aspect(np.array([[100, 100, 40, 40]]), 2.0, (640, 480), 0.0)[0]
    assert box[2] == pytest.approx(80) and box[3] == pytest.approx(40)
    assert box[0] + box[2] / 2 == pytest.approx(120) and box[1] + box[3] / 2 == pytest.approx(120)
