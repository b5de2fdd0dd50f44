"""service.pipeline.sliding and service.pipeline.predictor: window grid, working copy, NMS,
batched prediction."""

from __future__ import annotations

import numpy as np
import pytest
from service_support import REAL

from service.core.paths import DEFAULT_MODEL
from service.core.preprocess import DecodedImage
from service.pipeline.model import PoseModel
from service.pipeline.predictor import Predictor
from service.pipeline.sliding import (
    SlidingWindows,
    best_window,
    to_full_resolution,
    window_batch,
    working_copy,
)
from service.settings import Settings

GRID = SlidingWindows(aspect=4 / 3, scales=(1.0, 0.8, 0.6), stride=20, max_windows=256)


def boxes_for(w: int, h: int, grid: SlidingWindows = GRID) -> np.ndarray:
    return grid(np.zeros((h, w, 3), np.uint8))


@pytest.mark.parametrize(("w", "h"), [(120, 90), (160, 90), (90, 120), (300, 90), (7, 5)])
def test_windows_lie_inside_and_keep_the_aspect(w: int, h: int) -> None:
    boxes = boxes_for(w, h)
    assert len(boxes) == len(np.unique(boxes, axis=0)) > 0
    x, y, bw, bh = boxes.T
    assert (x >= 0).all() and (y >= 0).all() and (x + bw <= w).all() and (y + bh <= h).all()
    big = boxes[bw >= 20]
    assert np.allclose(big[:, 2] / big[:, 3], 4 / 3, atol=0.05)


def test_default_grid_on_the_working_copy_of_a_4_by_3_photo() -> None:
    settings = Settings()
    grid = SlidingWindows(4 / 3, settings.sliding_scales, settings.sliding_stride, 256)
    image = DecodedImage(np.zeros((120, 160, 3), np.uint8), width=640, height=480)
    work, _ = working_copy(image, (80, 60), settings.sliding_resolution)
    boxes = grid(work)
    assert work.shape == (60, 80, 3) and len(boxes) == 1 + 4 + 4
    assert {(int(b[2]), int(b[3])) for b in boxes} == {(80, 60), (64, 48), (52, 39)}
    small = boxes[boxes[:, 2] == 52]
    assert sorted(set(small[:, 0].tolist())) == [0, 28]  # ~20 px steps spanning it all
    assert len(boxes_for(120, 90)) == 1 + 4 + 9  # GRID (scales 1, 0.8, 0.6) on a 120x90 copy


@pytest.mark.parametrize("input_size", [(40, 30), (80, 60), (160, 120)])
def test_same_windows_for_any_network_size(input_size: tuple[int, int]) -> None:
    """The stride follows the input width: the window count (the cost ratio) stays put."""
    settings = Settings()
    grid = SlidingWindows.for_network(input_size, settings.sliding_scales, 20, 256)
    image = DecodedImage(np.zeros((480, 640, 3), np.uint8), width=640, height=480)
    work, _ = working_copy(image, input_size, settings.sliding_resolution)
    assert work.shape[:2] == (input_size[1], input_size[0])
    assert len(grid(work)) == 9


def test_stride_grows_to_respect_max_windows() -> None:
    capped = SlidingWindows(aspect=4 / 3, scales=(1.0, 0.5), stride=1, max_windows=50)
    assert len(boxes_for(400, 300, capped)) <= 50
    assert len(boxes_for(2000, 90)) <= 256


def test_working_copy_maps_back_to_full_resolution() -> None:
    image = DecodedImage(np.zeros((120, 160, 3), np.uint8), width=640, height=480)
    work, scale = working_copy(image, (80, 60), 1.5)
    assert work.shape == (90, 120, 3) and scale == (640 / 120, 480 / 90)
    portrait = DecodedImage(np.zeros((160, 120, 3), np.uint8), width=480, height=640)
    work, _ = working_copy(portrait, (80, 60), 1.5)
    assert work.shape == (160, 120, 3)  # the largest 4:3 window is 120x90 inside it


def test_window_batch_shapes() -> None:
    image = np.random.default_rng(0).integers(0, 255, (90, 120, 3), dtype=np.uint8)
    batch = window_batch(image, boxes_for(120, 90), (80, 60))
    assert batch.shape == (14, 3, 60, 80) and batch.dtype == np.float32


def _probs(rows: list[tuple[int, float]]) -> np.ndarray:
    """One row per window: the given class gets `p`, the rest share 1 - p."""
    out = np.empty((len(rows), 9))
    for i, (cls, p) in enumerate(rows):
        out[i] = (1 - p) / 8
        out[i, cls] = p
    return out


def test_best_window_nms_keeps_the_best_of_overlapping_windows() -> None:
    boxes = np.array([[0, 0, 40, 30], [2, 1, 40, 30], [60, 50, 40, 30], [10, 10, 40, 30]])
    probs = _probs([(3, 0.8), (3, 0.9), (5, 0.7), (0, 0.95)])
    answer = best_window(boxes, probs, nms_iou=0.3)
    assert answer.class_id == 3 and answer.box == (2, 1, 40, 30)
    assert [(d[0], d[1]) for d in answer.detections] == [((2, 1, 40, 30), 3), ((60, 50, 40, 30), 5)]
    assert np.array_equal(answer.probabilities, probs[1])


def test_best_window_all_background_is_class_0_without_box() -> None:
    probs = _probs([(0, 0.6), (0, 0.9), (0, 0.5)])
    answer = best_window(np.array([[0, 0, 4, 3]] * 3), probs, nms_iou=0.3)
    assert answer.class_id == 0 and answer.box is None and answer.detections == []
    assert np.array_equal(answer.probabilities, probs[1])


@pytest.fixture(scope="module")
def model() -> PoseModel:
    return PoseModel.load(DEFAULT_MODEL)


def test_batched_answers_equal_one_by_one(model: PoseModel) -> None:
    predictor = Predictor(model, Settings())
    images = [(p.name, p.read_bytes()) for p in sorted(REAL.glob("left0*.jpg"))[:4]]
    for mode in ("whole", "sliding"):
        together = predictor.predict(images, mode).results
        for image, result in zip(images, together, strict=True):
            alone = predictor.predict([image], mode).results[0]
            assert alone.class_id == result.class_id and alone.box == result.box
            # batch sizes round differently in onnxruntime; the alignment's steps carry it
            assert np.allclose(alone.probabilities, result.probabilities, atol=1e-3)
            assert abs(sum(result.probabilities) - 1) < 1e-9


def test_boxes_map_back_to_photo_pixels() -> None:
    assert to_full_resolution((16, 12, 48, 36), (8.0, 8.0), (640, 480)) == (128, 96, 384, 288)
    assert to_full_resolution((0, 0, 80, 60), (6.0, 6.0), (480, 360)) == (0, 0, 480, 360)
    assert to_full_resolution((40, 30, 80, 60), (1 / 60, 1 / 60), (1, 1)) == (0, 0, 1, 1)


def test_sliding_answers_on_real_photos(model: PoseModel) -> None:
    predictor = Predictor(model, Settings())
    images = [(p.name, p.read_bytes()) for p in sorted(REAL.glob("right0*.jpg"))[:4]]
    for answer in predictor.predict(images, "sliding").results:
        if answer.class_id == 0:
            assert answer.box is None and answer.detections == []
            continue
        box, detections = answer.box, answer.detections or []
        assert box is not None and detections[0].box == box
        assert box.x >= 0 and box.y >= 0 and box.x + box.w <= 640 and box.y + box.h <= 480
        assert box.w >= 640 * min(Settings().sliding_scales) - 1
        scores = [d.confidence for d in detections]
        assert scores == sorted(scores, reverse=True) and scores[0] == answer.confidence


def test_another_box_generator_plugs_in(model: PoseModel) -> None:
    """What a `proposals` mode would do: supply boxes, get the same answer shape."""

    def whole_frame(image: np.ndarray) -> np.ndarray:
        return np.array([[0, 0, image.shape[1], image.shape[0]]])

    predictor = Predictor(model, Settings(), boxes=whole_frame)
    result = predictor.predict([(None, (REAL / "right03.jpg").read_bytes())], "sliding").results[0]
    if result.class_id != 0:
        assert result.box is not None and (result.box.w, result.box.h) == (640, 480)
    assert len(result.detections or []) <= 1
