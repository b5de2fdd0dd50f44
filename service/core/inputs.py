"""The network input contract: the SPEC image sizes and the SPEC camera at those sizes.

Size 1 is 80x60 and size 2 is 160x120 pixels (SPEC section 6). The SPEC camera's intrinsics
are given for 160x120 and scale with the image width (SPEC section 2).
"""

from __future__ import annotations

#: SPEC size index -> input size (W, H) in pixels.
SIZES: dict[int, tuple[int, int]] = {1: (80, 60), 2: (160, 120)}
#: The same, for command-line help texts.
SIZE_HELP = "SPEC size: " + ", ".join(f"{i} = {w}x{h}" for i, (w, h) in SIZES.items())
#: Pinhole intrinsics (fx, fy, u0, v0) in pixels for 160x120 images (SPEC section 2).
SPEC_FOCAL_160: tuple[float, float, float, float] = (206.0358, 205.1238, 80.0534, 49.8627)


def size_index(size: int | tuple[int, int]) -> int:
    """SPEC size 1 or 2 from either the index itself or an image size (W, H) in pixels."""
    if isinstance(size, int) and not isinstance(size, bool):
        if size in SIZES:
            return size
    else:
        for index, wh in SIZES.items():
            if isinstance(size, tuple) and tuple(size) == wh:
                return index
    raise ValueError(f"size must be 1 (80x60) or 2 (160x120), got {size!r}")


def spec_camera(width_px: float) -> tuple[float, float, float, float]:
    """The SPEC camera's (fx, fy, u0, v0) in pixels of an image `width_px` wide."""
    s = width_px / SIZES[2][0]
    fx, fy, u0, v0 = SPEC_FOCAL_160
    return fx * s, fy * s, u0 * s, v0 * s


def spec_fx(width_px: float) -> float:
    """The SPEC camera's fx (px) in an image `width_px` wide."""
    return spec_camera(width_px)[0]


def focal_scale(fx_px: float, width_px: float) -> float:
    """fx (px) of an image `width_px` wide as a multiple of the SPEC camera's fx at that width."""
    return fx_px / spec_fx(width_px)
