"""SPEC 6 blur: fspecial-style kernels, a direct-formula check, sharpness falls with the level."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from service.core.blur import KERNELS, blur_image, gaussian_kernel, gaussian_taps
from service.core.inputs import size_index


def _fspecial(k: int, sigma: float) -> np.ndarray:
    """Matlab's fspecial('gaussian', k, sigma) written out tap by tap."""
    h = np.zeros((k, k))
    for i in range(k):
        for j in range(k):
            x, y = j - (k - 1) / 2, i - (k - 1) / 2
            h[i, j] = np.exp(-(x * x + y * y) / (2 * sigma * sigma))
    return h / h.sum()


def _direct_blur(image: np.ndarray, k: int, sigma: float) -> np.ndarray:
    """Correlation with the kernel anchored at tap (k-1)//2, borders replicated."""
    kernel, a = _fspecial(k, sigma), (k - 1) // 2
    h, w = image.shape[:2]
    out = np.zeros(image.shape, float)
    for i in range(k):
        for j in range(k):
            rows = np.clip(np.arange(h) + i - a, 0, h - 1)
            cols = np.clip(np.arange(w) + j - a, 0, w - 1)
            out += kernel[i, j] * image[rows][:, cols]
    return out


@pytest.mark.parametrize("k,sigma", [(2, 1.0), (4, 2.0), (5, 3.0), (10, 5.0)])
def test_kernel_is_fspecial(k, sigma):
    assert np.allclose(gaussian_kernel(k, sigma), _fspecial(k, sigma))
    taps = gaussian_taps(k, sigma)
    assert taps.sum() == pytest.approx(1.0) and np.allclose(taps, taps[::-1])
    if k == 2:  # even k: taps at -0.5 and +0.5, equal weights
        assert np.allclose(taps, [0.5, 0.5])


@pytest.mark.parametrize("size", [1, 2])
@pytest.mark.parametrize("level", [1, 2, 3])
def test_blur_matches_direct_formula(size, level):
    rng = np.random.default_rng(level)
    image = rng.integers(0, 256, (60, 80, 3), dtype=np.uint8)
    k, sigma = KERNELS[size][level]
    expected = _direct_blur(image.astype(float), k, sigma)
    got = blur_image(image, level, size).astype(float)
    assert got.shape == image.shape
    assert np.abs(got - expected).max() <= 1.0  # uint8 rounding


def test_level_zero_is_identity_and_size_by_pixels():
    image = np.arange(60 * 80 * 3, dtype=np.uint8).reshape(60, 80, 3)
    assert blur_image(image, 0, 1) is image
    assert np.array_equal(blur_image(image, 2, (80, 60)), blur_image(image, 2, 1))
    assert size_index((160, 120)) == 2


@pytest.mark.parametrize("size,wh", [(1, (80, 60)), (2, (160, 120))])
def test_sharpness_falls_as_level_rises(size, wh):
    tile = np.kron((np.indices((12, 16)).sum(axis=0) % 2) * 255, np.ones((10, 10)))
    image = np.repeat(tile[: wh[1], : wh[0], None], 3, axis=2).astype(np.uint8)
    sharpness = [
        cv2.Laplacian(
            cv2.cvtColor(blur_image(image, lv, size), cv2.COLOR_RGB2GRAY), cv2.CV_64F
        ).var()
        for lv in (0, 1, 2, 3)
    ]
    assert all(a > b for a, b in zip(sharpness, sharpness[1:], strict=False)), sharpness


@pytest.mark.parametrize("bad", [(4, 1), (-1, 1), (1, 3), (1, (100, 100))])
def test_bad_level_or_size(bad):
    level, size = bad
    with pytest.raises(ValueError, match="blur level|size"):
        blur_image(np.zeros((60, 80, 3), np.uint8), level, size)
