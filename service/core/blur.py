"""Gaussian blur levels of the data sets (SPEC section 6), Matlab fspecial-style kernels.

Level 0 is no blur; levels 1-3 use a normalised k x k Gaussian of standard deviation s
(pixels) that depends on the image size (size 1 = 80x60, size 2 = 160x120). For an even k the
taps sit at -(k-1)/2 ... (k-1)/2 like fspecial; the kernel's anchor is tap (k-1)//2 like
Matlab's imfilter, and image borders are replicated.
"""

from __future__ import annotations

from functools import cache

import cv2
import numpy as np

from service.core.inputs import size_index

BLUR_LEVELS = (0, 1, 2, 3)
#: (k taps, sigma px) per size (1, 2) and level (1..3).
KERNELS: dict[int, dict[int, tuple[int, float]]] = {
    1: {1: (2, 1.0), 2: (4, 2.0), 3: (6, 3.0)},
    2: {1: (2, 2.0), 2: (5, 3.0), 3: (10, 5.0)},
}


@cache
def gaussian_taps(k: int, sigma: float) -> np.ndarray:
    """1-D normalised Gaussian (k,) float64 at positions -(k-1)/2 ... (k-1)/2 (fspecial)."""
    if k < 1 or sigma <= 0:
        raise ValueError(f"need k >= 1 and sigma > 0, got k={k}, sigma={sigma}")
    x = np.arange(k) - (k - 1) / 2.0
    g = np.exp(-(x**2) / (2.0 * sigma**2))
    return g / g.sum()


def gaussian_kernel(k: int, sigma: float) -> np.ndarray:
    """2-D normalised fspecial('gaussian', k, sigma) kernel (k, k) float64 (the outer product)."""
    g = gaussian_taps(k, sigma)
    return np.outer(g, g)


def blur_image(rgb: np.ndarray, level: int, size: int | tuple[int, int]) -> np.ndarray:
    """Blur an image uint8 [H, W, C] with SPEC level 0..3 for size 1/2 (or (W, H)) -> same shape.

    The kernel is chosen by the data set's size, not the array's shape, so that an image of
    any size gets the size's kernel. Level 0 returns the input unchanged.
    """
    if level not in BLUR_LEVELS:
        raise ValueError(f"blur level must be 0, 1, 2 or 3, got {level!r}")
    if level == 0:  # no kernel: any size
        return rgb
    index = size_index(size)
    k, sigma = KERNELS[index][level]
    g = gaussian_taps(k, sigma)
    anchor = ((k - 1) // 2, (k - 1) // 2)
    return cv2.sepFilter2D(rgb, -1, g, g, anchor=anchor, borderType=cv2.BORDER_REPLICATE)
