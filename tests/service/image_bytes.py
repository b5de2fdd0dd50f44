"""Hand-made image bytes for the preprocessing and service tests (EXIF, lying headers)."""

from __future__ import annotations

import io
import struct
import zlib


def with_exif_orientation(jpeg: bytes, orientation: int) -> bytes:
    """Insert an APP1 Exif segment with the given orientation tag after SOI."""
    tiff = b"II*\x00" + struct.pack("<IH", 8, 1) + struct.pack("<HHII", 0x0112, 3, 1, orientation)
    payload = b"Exif\x00\x00" + tiff + struct.pack("<I", 0)
    return jpeg[:2] + b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload + jpeg[2:]


def png_claiming(w: int, h: int, padding: int = 0) -> bytes:
    """A PNG signature + IHDR claiming w x h RGB pixels, `padding` zero bytes, no image data."""
    ihdr = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    chunk = struct.pack(">I", 13) + b"IHDR" + ihdr + struct.pack(">I", zlib.crc32(b"IHDR" + ihdr))
    return b"\x89PNG\r\n\x1a\n" + chunk + bytes(padding)


def with_exif_focal(
    image: bytes, f35: int, exif_size: tuple[int, int] | None = None, fmt: str = "PNG"
) -> bytes:
    """`image` re-encoded by Pillow as `fmt` (PNG: the same pixels) with EXIF tags: the 35 mm
    equivalent focal length `f35` (mm) and, if given, the pixel size (W, H) it was taken at."""
    from PIL import Image
    from PIL.ExifTags import IFD, Base

    exif = Image.Exif()
    tags = exif.get_ifd(IFD.Exif)
    tags[Base.FocalLengthIn35mmFilm] = f35
    if exif_size is not None:
        tags[Base.ExifImageWidth], tags[Base.ExifImageHeight] = exif_size
    out = io.BytesIO()
    with Image.open(io.BytesIO(image)) as decoded:
        decoded.save(out, fmt, exif=exif.tobytes())
    return out.getvalue()


def black_png(w: int, h: int) -> bytes:
    """A real, decodable black RGB PNG of w x h pixels, made without holding its pixels: a
    decompression bomb (7000 x 7000 is ~145 kB of file for 147 MB of pixels)."""
    row = bytes(1 + 3 * w)  # filter byte 0, then black pixels
    deflate = zlib.compressobj(9)
    rows = 64
    data = b"".join(deflate.compress(row * min(rows, h - y)) for y in range(0, h, rows))
    data += deflate.flush()

    def chunk(kind: bytes, body: bytes) -> bytes:
        crc = struct.pack(">I", zlib.crc32(kind + body))
        return struct.pack(">I", len(body)) + kind + body + crc

    ihdr = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", data) + chunk(b"IEND", b"")
