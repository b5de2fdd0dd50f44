"""Sliding-window detection (SPEC 9): boxes -> batched classification -> NMS -> best window.

Frames: boxes are int [K, 4] rows (x, y, w, h) in pixels of the image handed to the box
generator (the *working copy*, see `working_copy`). Any `BoxGenerator` can replace the window
grid, e.g. an object-proposal generator for an `objectness` mode.

Default cost (80x60 network, 640x480 photo): the working copy is 80x60 (the largest window
spans `resolution` = 1 network input, so the scale-1 window is exactly the whole-mode input),
windows at scales 1, 0.8 and 0.65 of it (80x60, 64x48, 52x39, each resized to 80x60) every
~20 working pixels (16 and 28 here: the grid spans the copy evenly; x8 in photo pixels):
1 + 4 + 4 = 9 windows in one batched call, about
5x the cost of whole mode (the network dominates: ~0.85 ms per window on one core). Scales
1, 0.8, 0.6 give 11 windows (~6x); `resolution` 1.5 (120x90 copy, 14 windows, ~7x) keeps the
small windows sharper. The window count does not depend on the photo's size, only its aspect,
nor on the network's input size (the stride scales with it: 40 px for a 160x120 network).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from service.core.preprocess import DecodedImage, resize_rgb, to_network_input

#: RGB uint8 [H, W, 3] -> int [K, 4] boxes (x, y, w, h) inside that image.
BoxGenerator = Callable[[np.ndarray], np.ndarray]

#: The stride is given in pixels at SPEC size 1 (80 px wide network input) and scaled with the
#: network's input width, so a 160x120 network gets the same windows (and ~5x cost) as 80x60.
STRIDE_REFERENCE_WIDTH = 80


def _positions(extent: int, size: int, stride: float) -> np.ndarray:
    """Window origins along one axis: first at 0, last at extent - size, step ~ stride."""
    n = max(1, round((extent - size) / stride) + 1)
    return np.rint(np.linspace(0, extent - size, n)).astype(np.int64)


@dataclass(frozen=True)
class SlidingWindows:
    """Box generator: windows of the network's aspect at several scales on a regular grid.

    Scale 1 is the largest window of aspect `aspect` (W/H) that fits the image; `stride` is in
    pixels of the image given; it grows by 25 % steps while there are more than `max_windows`.
    """

    aspect: float
    scales: Sequence[float]
    stride: float
    max_windows: int

    @classmethod
    def for_network(
        cls, input_size: tuple[int, int], scales: Sequence[float], stride: float, max_windows: int
    ) -> SlidingWindows:
        """The grid for a network of `input_size` (W, H); `stride` in size-1 pixels."""
        iw, ih = input_size
        return cls(iw / ih, tuple(scales), stride * iw / STRIDE_REFERENCE_WIDTH, max_windows)

    def _sizes(self, width: int, height: int) -> list[tuple[int, int]]:
        fit_w = min(float(width), height * self.aspect)
        fit_h = fit_w / self.aspect
        return [
            (min(width, max(1, round(fit_w * s))), min(height, max(1, round(fit_h * s))))
            for s in self.scales
        ]

    def __call__(self, image: np.ndarray) -> np.ndarray:
        height, width = image.shape[:2]
        sizes, stride = self._sizes(width, height), self.stride
        while True:
            grids = [
                (_positions(width, w, stride), _positions(height, h, stride), w, h)
                for w, h in sizes
            ]
            if sum(len(xs) * len(ys) for xs, ys, _, _ in grids) <= self.max_windows:
                break
            stride *= 1.25
        boxes = [(x, y, w, h) for xs, ys, w, h in grids for y in ys.tolist() for x in xs.tolist()]
        return np.unique(np.asarray(boxes, dtype=np.int64).reshape(-1, 4), axis=0)  # tiny images


def working_min_size(input_size: tuple[int, int], resolution: float) -> tuple[int, int]:
    """Smallest (W, H) the working copy's largest window has: `resolution` network inputs."""
    return math.ceil(input_size[0] * resolution), math.ceil(input_size[1] * resolution)


def working_copy(
    image: DecodedImage, input_size: tuple[int, int], resolution: float
) -> tuple[np.ndarray, tuple[float, float]]:
    """Resize so the largest input-aspect window spans `resolution` x the network input.

    Returns the RGB uint8 copy and (sx, sy), full-resolution pixels per working pixel.
    """
    iw, ih = input_size
    fit_w = min(float(image.width), image.height * iw / ih)
    k = resolution * iw / fit_w
    size = (max(1, round(image.width * k)), max(1, round(image.height * k)))
    return resize_rgb(image.rgb, size), (image.width / size[0], image.height / size[1])


def to_full_resolution(
    box: tuple[int, int, int, int], scale: tuple[float, float], size: tuple[int, int]
) -> tuple[int, int, int, int]:
    """Working-copy box (x, y, w, h) -> pixels of the full image of `size` (W, H), clipped to
    it, at least 1 px wide and high; `scale` = (sx, sy) from `working_copy`."""
    (x, y, w, h), (sx, sy) = box, scale
    x0, y0 = min(round(x * sx), size[0] - 1), min(round(y * sy), size[1] - 1)
    return (
        x0,
        y0,
        max(1, min(round(w * sx), size[0] - x0)),
        max(1, min(round(h * sy), size[1] - y0)),
    )


def window_batch(image: np.ndarray, boxes: np.ndarray, input_size: tuple[int, int]) -> np.ndarray:
    """Crop each box of RGB uint8 `image` -> float32 [K, 3, H, W] network inputs."""
    crops = [to_network_input(image[y : y + h, x : x + w], input_size) for x, y, w, h in boxes]
    return np.stack(crops) if crops else np.zeros((0, 3, input_size[1], input_size[0]), np.float32)


@dataclass(frozen=True)
class WindowAnswer:
    """The answer of one image: best window's class, probabilities [9] and box (or None)."""

    class_id: int
    probabilities: np.ndarray
    box: tuple[int, int, int, int] | None
    detections: list[tuple[tuple[int, int, int, int], int, float]]  # (box, class, score)


def best_window(boxes: np.ndarray, probs: np.ndarray, nms_iou: float) -> WindowAnswer:
    """Drop windows whose best class is 0, NMS the rest; the top window is the answer.

    `boxes` int [K, 4], `probs` [K, 9]. When every window says 0 the answer is class 0, box
    None, with the probabilities of the window most sure of it.
    """
    classes = probs.argmax(axis=1)
    kept = np.flatnonzero(classes != 0)
    if kept.size == 0:
        top = int(probs[:, 0].argmax())
        return WindowAnswer(0, probs[top], None, [])
    scores = probs[kept, classes[kept]]
    order = cv2.dnn.NMSBoxes(boxes[kept].tolist(), scores.tolist(), 0.0, nms_iou)
    picks = [int(kept[i]) for i in np.asarray(order).reshape(-1)]
    picks.sort(key=lambda k: -probs[k, classes[k]])
    detections = [
        ((int(x), int(y), int(w), int(h)), int(classes[k]), float(probs[k, classes[k]]))
        for k, (x, y, w, h) in ((k, boxes[k]) for k in picks)
    ]
    best = picks[0]
    return WindowAnswer(int(classes[best]), probs[best], detections[0][0], detections)
