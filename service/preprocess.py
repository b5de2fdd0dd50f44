"""Bytes -> network input: the single preprocessing used by training, evaluation and serving.

The network input is float32 [3, H, W], RGB, values in [0, 1]; mean/std normalisation is
inside the network (and the exported ONNX graph), not here.
"""

from __future__ import annotations

import cv2
import numpy as np


class ImageDecodeError(ValueError):
    """The bytes are not an image OpenCV can decode."""


def decode_image(data: bytes) -> np.ndarray:
    """Decode image bytes (JPEG, PNG, WebP, BMP, ...) to RGB uint8 [H, W, 3].

    EXIF orientation is applied; grey, alpha and 16-bit images become 8-bit RGB.
    """
    if not data:
        raise ImageDecodeError("empty image")
    buf = np.frombuffer(data, dtype=np.uint8)
    bgr = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    if bgr is None:
        raise ImageDecodeError("could not decode the image (not a supported image format?)")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def resize_rgb(rgb: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Resize RGB uint8 [H, W, 3] to `size` = (W, H) with area interpolation (linear to upscale)."""
    w, h = size
    if rgb.shape[1] == w and rgb.shape[0] == h:
        return rgb
    shrinking = rgb.shape[1] >= w and rgb.shape[0] >= h
    interp = cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR
    return cv2.resize(rgb, (w, h), interpolation=interp)


def to_network_input(rgb: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """RGB uint8 [H0, W0, 3] -> float32 [3, H, W] in [0, 1] for a network of input `size` (W, H)."""
    small = resize_rgb(rgb, size)
    return np.ascontiguousarray(small.transpose(2, 0, 1), dtype=np.float32) / np.float32(255.0)
