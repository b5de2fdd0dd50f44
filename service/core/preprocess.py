"""Bytes -> network input: the single preprocessing used by training, evaluation and serving.

The network input is float32 [3, H, W], RGB, values in [0, 1]; mean/std normalisation is
inside the network (and the exported ONNX graph), not here.

Decoding is guarded: the header is read first (PNG IHDR, JPEG SOF, WebP VP8/VP8L/VP8X, BMP,
GIF) so that a decompression bomb is refused before any pixel is allocated, and a JPEG much
larger than needed is decoded at 1/2, 1/4 or 1/8 scale by libjpeg (DCT scaling).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

ImageFormat = Literal["jpeg", "png", "webp", "bmp", "gif"]

SUPPORTED_FORMATS = "JPEG, PNG, WebP, BMP or GIF"

# JPEG start-of-frame markers (baseline, progressive, lossless, arithmetic...): not C4/C8/CC.
_JPEG_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
_JPEG_SOS, _JPEG_EOI = 0xDA, 0xD9  # start of scan, end of image
# libjpeg DCT scaling: reduction factor -> imdecode flags (output stays RGB, 3 channels).
_REDUCED_RGB = {
    2: cv2.IMREAD_REDUCED_GRAYSCALE_2 | cv2.IMREAD_COLOR_RGB,
    4: cv2.IMREAD_REDUCED_GRAYSCALE_4 | cv2.IMREAD_COLOR_RGB,
    8: cv2.IMREAD_REDUCED_GRAYSCALE_8 | cv2.IMREAD_COLOR_RGB,
}


class ImageDecodeError(ValueError):
    """The bytes are not an image OpenCV can decode."""


class ImageTooLargeError(ImageDecodeError):
    """The image header announces more pixels than allowed (decompression bomb guard)."""


@dataclass(frozen=True)
class ImageHeader:
    """What the file header says, before decoding: stored size in pixels (before EXIF rotation)."""

    format: ImageFormat
    width: int
    height: int


@dataclass(frozen=True)
class DecodedImage:
    """A decoded image, possibly at reduced scale.

    `rgb` is uint8 [h, w, 3]; `width` x `height` is the full-resolution size in pixels after
    EXIF orientation, the frame in which boxes are reported (h/height == w/width up to rounding).
    """

    rgb: np.ndarray
    width: int
    height: int


def _u16be(data: bytes, at: int) -> int:
    return int.from_bytes(data[at : at + 2], "big")


def _jpeg_header(data: bytes) -> tuple[int, int]:
    """(width, height) from the first SOF segment (segments are walked up to the first scan)."""
    i, size = 2, None
    while i + 4 <= len(data):
        if data[i] != 0xFF:
            raise ImageDecodeError("corrupt JPEG: bad marker structure")
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker == 0x01 or 0xD0 <= marker <= 0xD7:  # stand-alone markers
            i += 2
            continue
        if marker == _JPEG_EOI:
            break
        length = _u16be(data, i + 2)
        if length < 2:
            raise ImageDecodeError("corrupt JPEG: bad segment length")
        if marker in _JPEG_SOF:
            if i + 9 > len(data):
                break
            size = (_u16be(data, i + 7), _u16be(data, i + 5))
        if marker == _JPEG_SOS:
            if size is None:
                raise ImageDecodeError("corrupt JPEG: scan before frame header")
            return size
        i += 2 + length
    raise ImageDecodeError("truncated JPEG: no complete frame header and scan")


def _webp_header(data: bytes) -> tuple[int, int]:
    chunk = data[12:16]
    if chunk == b"VP8X" and len(data) >= 30:
        return 1 + int.from_bytes(data[24:27], "little"), 1 + int.from_bytes(data[27:30], "little")
    if chunk == b"VP8L" and len(data) >= 25 and data[20] == 0x2F:
        bits = int.from_bytes(data[21:25], "little")
        return (bits & 0x3FFF) + 1, ((bits >> 14) & 0x3FFF) + 1
    if chunk == b"VP8 " and len(data) >= 30 and data[23:26] == b"\x9d\x01\x2a":
        w, h = struct.unpack("<HH", data[26:30])
        return w & 0x3FFF, h & 0x3FFF
    raise ImageDecodeError("truncated or corrupt WebP header")


def _bmp_header(data: bytes) -> tuple[int, int]:
    if len(data) >= 22 and int.from_bytes(data[14:18], "little") == 12:  # OS/2 core header
        w, h = struct.unpack("<HH", data[18:22])
        return w, h
    if len(data) < 26:
        raise ImageDecodeError("truncated BMP header")
    w, h = struct.unpack("<ii", data[18:26])
    return w, abs(h)  # negative height = top-down rows


def image_header(data: bytes) -> ImageHeader:
    """Format and stored size (pixels) from the first bytes, without decoding.

    Raises ImageDecodeError for an unknown format or a truncated/corrupt header.
    """
    if not data:
        raise ImageDecodeError("empty image")
    fmt: ImageFormat
    if data.startswith(b"\x89PNG\r\n\x1a\n"):
        if len(data) < 24 or data[12:16] != b"IHDR":
            raise ImageDecodeError("truncated or corrupt PNG header")
        fmt, (w, h) = "png", struct.unpack(">II", data[16:24])
    elif data.startswith(b"\xff\xd8"):
        fmt, (w, h) = "jpeg", _jpeg_header(data)
    elif data[:4] == b"RIFF" and data[8:12] == b"WEBP":
        fmt, (w, h) = "webp", _webp_header(data)
    elif data[:2] == b"BM":
        fmt, (w, h) = "bmp", _bmp_header(data)
    elif data[:6] in (b"GIF87a", b"GIF89a") and len(data) >= 10:
        fmt, (w, h) = "gif", struct.unpack("<HH", data[6:10])
    else:
        raise ImageDecodeError(f"not an image in a supported format ({SUPPORTED_FORMATS})")
    if w <= 0 or h <= 0:
        raise ImageDecodeError(f"{fmt.upper()} header gives an empty size {w}x{h}")
    return ImageHeader(fmt, w, h)


def _jpeg_reduction(header: ImageHeader, min_size: tuple[int, int]) -> int:
    """Largest libjpeg scale-down 8/4/2 keeping both sides >= max(min_size) (any EXIF turn)."""
    need, short = max(min_size), min(header.width, header.height)
    return next((f for f in (8, 4, 2) if short / f >= need), 1)


def _reduction(header: ImageHeader, min_size: tuple[int, int] | None) -> int:
    """The scale-down `load_image` decodes at: libjpeg's for a JPEG with `min_size`, else 1."""
    return _jpeg_reduction(header, min_size) if header.format == "jpeg" and min_size else 1


def decoded_pixels(header: ImageHeader, min_size: tuple[int, int] | None = None) -> int:
    """The pixels `load_image` allocates for an image of `header` with `min_size`: the stored
    size, or libjpeg's reduced size for a large JPEG (each side divided, rounded up)."""
    factor = _reduction(header, min_size)
    return -(-header.width // factor) * -(-header.height // factor)


def load_image(
    data: bytes,
    *,
    max_pixels: int | None = None,
    min_size: tuple[int, int] | None = None,
    header: ImageHeader | None = None,
) -> DecodedImage:
    """Decode image bytes to RGB uint8, refusing more than `max_pixels` before decoding.

    EXIF orientation is applied; grey, alpha (dropped) and 16-bit images become 8-bit RGB.
    With `min_size` = (W, H), a JPEG at least twice that size on its short side is decoded at
    reduced scale (both sides stay >= max(W, H)), which is several times faster. `header`:
    the bytes' `image_header` where the caller read it already.
    """
    header = header or image_header(data)
    pixels = header.width * header.height
    if max_pixels is not None and pixels > max_pixels:
        raise ImageTooLargeError(
            f"image is {header.width}x{header.height} = {pixels} pixels, "
            f"more than the limit of {max_pixels}"
        )
    factor = _reduction(header, min_size)
    flags = _REDUCED_RGB[factor] if factor > 1 else cv2.IMREAD_COLOR_RGB
    try:
        rgb = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), flags)
    except cv2.error as exc:
        raise ImageDecodeError(f"could not decode the {header.format.upper()} image") from exc
    if rgb is None or rgb.size == 0:
        raise ImageDecodeError(f"could not decode the {header.format.upper()} image (corrupt?)")
    return DecodedImage(rgb, *_upright_size(header, rgb))


def _upright_size(header: ImageHeader, decoded: np.ndarray) -> tuple[int, int]:
    """The full-resolution (W, H) of an image once EXIF turned it: the stored size, swapped
    where the decoded pixels [h, w, ...] (reduced or not) lie the other way (a 90/270 turn)."""
    w, h = header.width, header.height
    turned = (decoded.shape[1] > decoded.shape[0]) != (w > h) and w != h
    return (h, w) if turned else (w, h)


_REDUCED_GREY = {
    2: cv2.IMREAD_REDUCED_GRAYSCALE_2,
    4: cv2.IMREAD_REDUCED_GRAYSCALE_4,
    8: cv2.IMREAD_REDUCED_GRAYSCALE_8,
}


def load_grey(
    data: bytes, reduction: int = 1, header: ImageHeader | None = None
) -> tuple[np.ndarray, int, tuple[int, int]]:
    """Image bytes (size already guarded: `load_image`, `Predictor.admit`) -> grey
    uint8 [h, w], EXIF orientation applied, the factor it is reduced by and the full size
    (W, H) after EXIF orientation: a JPEG decoded at 1 / the largest of 8, 4, 2 not above
    `reduction` (libjpeg's DCT scaling), anything else at full size (factor 1). Pixel (u, v)
    of the reduced image is ((u + 0.5) f - 0.5, (v + 0.5) f - 0.5) of the full one. `header`:
    the bytes' `image_header` where the caller read it already."""
    header = header or image_header(data)
    jpeg = header.format == "jpeg"
    factor = next((f for f in (8, 4, 2) if f <= reduction), 1) if jpeg else 1
    flags = _REDUCED_GREY[factor] if factor > 1 else cv2.IMREAD_GRAYSCALE
    try:
        grey = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), flags)
    except cv2.error as exc:
        raise ImageDecodeError("could not decode the image") from exc
    if grey is None or grey.size == 0:
        raise ImageDecodeError("could not decode the image (corrupt?)")
    return grey, factor, _upright_size(header, grey)


def decode_image(data: bytes, max_pixels: int | None = None) -> np.ndarray:
    """Decode image bytes (JPEG, PNG, WebP, BMP, GIF) to RGB uint8 [H, W, 3] at full size.

    EXIF orientation is applied; grey, alpha and 16-bit images become 8-bit RGB. Raises
    ImageDecodeError (ImageTooLargeError above `max_pixels`) for anything else.
    """
    return load_image(data, max_pixels=max_pixels).rgb


def resize_rgb(rgb: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Resize RGB uint8 [H, W, 3] to `size` = (W, H) with area interpolation (linear to upscale)."""
    w, h = size
    if rgb.shape[1] == w and rgb.shape[0] == h:
        return rgb
    shrinking = rgb.shape[1] >= w and rgb.shape[0] >= h
    interp = cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR
    return cv2.resize(rgb, (w, h), interpolation=interp)


def landscape_pixels(uv: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """Pixels [..., 2] of an image of `image_size` (W0, H0) -> pixels of the image turned a
    quarter clockwise to landscape where it is a portrait, (u, v) -> (H0 - 1 - v, u); the same
    where it is not."""
    up: np.ndarray = np.asarray(uv, dtype=np.float64)
    if image_size[1] > image_size[0]:
        up = np.stack([image_size[1] - 1 - up[..., 1], up[..., 0]], -1)
    return up


def camera_pixels(uv: np.ndarray, image_size: tuple[int, int], size: tuple[int, int]) -> np.ndarray:
    """Pixels [..., 2] of an image of `image_size` (W0, H0) -> pixels of the landscape
    camera frame of `size` (W, H), W >= H: a portrait turned to landscape first
    (`landscape_pixels`: the camera turned), then scaled by the ratio of the longer sides
    (pixel centres kept). The one rule by which photos of one camera at several sizes and
    orientations are fitted together (`POST /v1/cameras`, `same_camera`)."""
    s = max(size) / max(image_size)
    out: np.ndarray = (landscape_pixels(uv, image_size) + 0.5) * s - 0.5
    return out


@dataclass(frozen=True)
class NetworkFrame:
    """How an image of `image_size` = (W0, H0) pixels becomes a network input of `size` =
    (W, H): a portrait image (H0 > W0) is first turned a quarter clockwise (a camera roll of
    -90 degrees, which leaves the camera centre, hence the pose class, unchanged), then
    resized to `size`, its aspect ratio not kept."""

    image_size: tuple[int, int]
    size: tuple[int, int]

    @property
    def turned(self) -> bool:
        """Whether the image is turned to landscape first."""
        return self.image_size[1] > self.image_size[0]

    @property
    def upright_size(self) -> tuple[int, int]:
        """(W, H) of the image once turned to landscape."""
        w, h = self.image_size
        return (h, w) if self.turned else (w, h)

    @property
    def pixel_aspect(self) -> float:
        """Height over width (fy / fx) of an input pixel in the scene: 1 for a 4:3 photo at
        160x120, 4/3 for a 16:9 one (the keypoint networks' `pixel_aspect` input)."""
        (w0, h0), (w, h) = self.upright_size, self.size
        return (h / h0) / (w / w0)

    def input_focal(self, fx: float) -> float:
        """The camera's focal length `fx` in pixels of the image (square pixels; of its
        height for a portrait, which is turned) -> in pixels of the input's width."""
        return fx * self.size[0] / self.upright_size[0]

    def _scale(self) -> np.ndarray:
        return np.asarray(self.size, np.float64) / np.asarray(self.upright_size, np.float64)

    def to_network(self, uv: np.ndarray) -> np.ndarray:
        """Image pixels [..., 2] (pixel centres at integers) -> network input pixels."""
        out: np.ndarray = (landscape_pixels(uv, self.image_size) + 0.5) * self._scale() - 0.5
        return out

    def to_image(self, uv: np.ndarray) -> np.ndarray:
        """Network input pixels [..., 2] -> image pixels (the inverse of `to_network`)."""
        up: np.ndarray = (np.asarray(uv, dtype=np.float64) + 0.5) / self._scale() - 0.5
        if self.turned:  # (u', v') -> (v', H0 - 1 - u')
            up = np.stack([up[..., 1], self.image_size[1] - 1 - up[..., 0]], -1)
        return up

    def input_of(self, rgb: np.ndarray) -> np.ndarray:
        """RGB uint8 [H0, W0, 3] (of `image_size`, or proportional to it) -> RGB uint8
        [H, W, 3], turned and resized."""
        upright = cv2.rotate(rgb, cv2.ROTATE_90_CLOCKWISE) if self.turned else rgb
        return resize_rgb(upright, self.size)


def to_network_input(rgb: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """RGB uint8 [H0, W0, 3] -> float32 [3, H, W] in [0, 1] for a network of input `size` (W, H)
    (`NetworkFrame`: a portrait image is turned to landscape first)."""
    small = NetworkFrame((rgb.shape[1], rgb.shape[0]), size).input_of(rgb)
    return np.ascontiguousarray(small.transpose(2, 0, 1), dtype=np.float32) / np.float32(255.0)
