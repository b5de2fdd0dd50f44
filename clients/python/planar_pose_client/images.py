"""Turn what a caller passes as an image into an upload: (file name, bytes, content type).

Accepted: a path (str or os.PathLike), raw encoded bytes (bytes, bytearray, memoryview), a binary
file object (anything with `.read()` returning bytes) or, when numpy is installed, a numpy array
of uint8 pixels: [H, W] grey, [H, W, 3] RGB or [H, W, 4] RGBA. Arrays are encoded losslessly as
PNG, with OpenCV when it is importable and otherwise with the small stdlib writer below (zlib).
Arrays are RGB like the service's own decoder: convert OpenCV's BGR first (cv2.cvtColor).

Everything here runs before a request is sent, so bad input fails fast with a precise message.
"""

from __future__ import annotations

import mimetypes
import os
import struct
import zlib
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, NamedTuple, TypeGuard, Union

if TYPE_CHECKING:
    import numpy as np

ImageInput = Union[str, "os.PathLike[str]", bytes, bytearray, memoryview, IO[bytes], "np.ndarray"]

# Leading bytes (at an offset) of the formats the service decodes: JPEG, PNG, WebP, BMP, GIF.
_SIGNATURES: tuple[tuple[bytes, int, str, str], ...] = (
    (b"\xff\xd8\xff", 0, "image/jpeg", "jpg"),
    (b"\x89PNG\r\n\x1a\n", 0, "image/png", "png"),
    (b"WEBP", 8, "image/webp", "webp"),
    (b"BM", 0, "image/bmp", "bmp"),
    (b"GIF8", 0, "image/gif", "gif"),
)
UNKNOWN_TYPE = "application/octet-stream"


class Upload(NamedTuple):
    """One image ready to send: the multipart file name, its encoded bytes, its content type."""

    filename: str
    data: bytes
    content_type: str


def sniff_type(data: bytes) -> tuple[str, str]:
    """(content type, file extension) of encoded image bytes from their signature; unknown
    bytes are `application/octet-stream` / "bin" and left for the service to judge."""
    for magic, offset, content_type, ext in _SIGNATURES:
        if data[offset : offset + len(magic)] == magic:
            return content_type, ext
    return UNKNOWN_TYPE, "bin"


def content_type_of(data: bytes, filename: str) -> str:
    """The content type to send: from the bytes when they are a known image format, else
    from the file name (so the service can tell a text file from a broken image), else
    `application/octet-stream`."""
    sniffed, _ = sniff_type(data)
    if sniffed != UNKNOWN_TYPE:
        return sniffed
    return mimetypes.guess_type(filename, strict=False)[0] or UNKNOWN_TYPE


def to_upload(image: ImageInput, index: int = 0) -> Upload:
    """Read or encode one image. `index` (its position in the batch) names nameless inputs:
    bytes become "image-<index>.<ext>", arrays "array-<index>.png".

    Raises FileNotFoundError / IsADirectoryError for a bad path, TypeError for an object that
    is not an image input, ValueError for an empty image or an array of the wrong shape/dtype.
    """
    if isinstance(image, (str, os.PathLike)):
        return _from_path(Path(image))
    if isinstance(image, (bytes, bytearray, memoryview)):
        data = bytes(image)
        _require_data(data, f"image {index} (bytes)")
        content_type, ext = sniff_type(data)
        return Upload(f"image-{index}.{ext}", data, content_type)
    if callable(getattr(image, "read", None)):
        return _from_file_object(image, index)
    if is_numpy_array(image):
        return Upload(f"array-{index}.png", encode_png(image), "image/png")
    raise TypeError(
        f"image {index}: unsupported type {type(image).__name__}; pass a path, bytes, a binary "
        "file object or a numpy uint8 array"
    )


def check_path(path: Path) -> None:
    """Raise FileNotFoundError / IsADirectoryError unless `path` is a file."""
    if not path.exists():
        raise FileNotFoundError(f"no such image file: {path}")
    if path.is_dir():
        raise IsADirectoryError(f"is a directory, not an image file: {path}")


def _from_path(path: Path) -> Upload:
    check_path(path)
    data = path.read_bytes()
    _require_data(data, str(path))
    return Upload(path.name, data, content_type_of(data, path.name))


def _from_file_object(file: Any, index: int) -> Upload:
    data = file.read()
    if isinstance(data, str):
        raise TypeError(f"image {index}: file object is in text mode; open it with 'rb'")
    if not isinstance(data, (bytes, bytearray)):
        raise TypeError(f"image {index}: .read() returned {type(data).__name__}, not bytes")
    name = getattr(file, "name", None)
    data = bytes(data)
    _require_data(data, str(name) if isinstance(name, str) else f"image {index} (file object)")
    filename = Path(name).name if isinstance(name, str) else f"image-{index}.{sniff_type(data)[1]}"
    return Upload(filename, data, content_type_of(data, filename))


def _require_data(data: bytes, what: str) -> None:
    if not data:
        raise ValueError(f"{what}: image is empty (0 bytes)")


def is_single_image(obj: object) -> bool:
    """True for an object that is one image even though it is iterable (a path string, bytes,
    a file object, an array), so that it is not mistaken for a list of images."""
    single = (str, os.PathLike, bytes, bytearray, memoryview)
    return isinstance(obj, single) or callable(getattr(obj, "read", None)) or is_numpy_array(obj)


def is_numpy_array(obj: object) -> TypeGuard[np.ndarray]:
    """True for a numpy array, without importing numpy when the caller never did."""
    return type(obj).__module__ == "numpy" and type(obj).__name__ == "ndarray"


def encode_png(pixels: np.ndarray) -> bytes:
    """Encode uint8 [H, W] grey, [H, W, 3] RGB or [H, W, 4] RGBA pixels as PNG bytes."""
    if pixels.dtype.name != "uint8":
        raise ValueError(f"array images must be uint8, got {pixels.dtype.name}")
    channels = 1 if pixels.ndim == 2 else pixels.shape[-1] if pixels.ndim == 3 else 0
    if channels not in (1, 3, 4) or pixels.shape[0] == 0 or pixels.shape[1] == 0:
        raise ValueError(
            f"array images must be [H, W], [H, W, 3] or [H, W, 4] with H, W > 0; "
            f"got shape {tuple(pixels.shape)}"
        )
    try:
        import cv2
    except ImportError:
        return _png_stdlib(pixels.tobytes(order="C"), pixels.shape[1], pixels.shape[0], channels)
    to_bgr = {1: None, 3: cv2.COLOR_RGB2BGR, 4: cv2.COLOR_RGBA2BGRA}[channels]
    ok, buf = cv2.imencode(".png", pixels if to_bgr is None else cv2.cvtColor(pixels, to_bgr))
    if not ok:
        raise ValueError(f"OpenCV could not encode the array of shape {tuple(pixels.shape)}")
    return bytes(buf.tobytes())


def _png_stdlib(raw: bytes, width: int, height: int, channels: int) -> bytes:
    """Minimal PNG writer (8-bit grey / RGB / RGBA, no filtering) for `raw` row-major pixels."""
    colour_type = {1: 0, 3: 2, 4: 6}[channels]
    stride = width * channels
    # Each scanline starts with its filter type byte, 0 = None.
    scanlines = b"".join(b"\x00" + raw[row * stride : (row + 1) * stride] for row in range(height))

    def chunk(kind: bytes, body: bytes) -> bytes:
        crc = zlib.crc32(kind + body) & 0xFFFFFFFF
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", crc)

    header = struct.pack(">IIBBBBB", width, height, 8, colour_type, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", header)
        + chunk(b"IDAT", zlib.compress(scanlines, 6))
        + chunk(b"IEND", b"")
    )
