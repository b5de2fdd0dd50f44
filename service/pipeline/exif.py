"""The camera's focal length from a photo's EXIF tags, in pixels of the photo as decoded.

From one photo the focal length is poorly observable (docs/service.md, `fx`), and a phone
writes it in the file: `FocalLengthIn35mmFilm`, the lens whose diagonal angle of view on a
36 x 24 mm frame is the photo's, gives fx = f35 x the image's diagonal / 43.27 mm (square
pixels, principal point near the centre). Cameras that only write the lens's own focal length
(`FocalLength`, mm) without the 35 mm equivalent are not read: the sensor size it needs is
not reliably in the tags.

That holds for the whole frame the camera wrote, resized or not, and not for a crop of it:
where the EXIF pixel size is given and the upload's aspect ratio differs from it by more than
1 %, the photo is taken as cropped and its tags are not used (a crop that keeps the aspect
ratio cannot be told from a resize). Unreadable or absurd tags (a 35 mm equivalent outside
8-800 mm) count as none: a photo is never refused for its EXIF.
"""

from __future__ import annotations

import io
import math
import struct

from PIL import Image, UnidentifiedImageError
from PIL.ExifTags import IFD, Base

FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)  # 43.27 mm
F35_RANGE_MM = (8.0, 800.0)  # 35 mm equivalents outside this are taken as wrong tags
ASPECT_TOLERANCE = 0.01  # relative; an upload of another aspect ratio than the EXIF's: a crop


def _number(value: object) -> float | None:
    """An EXIF rational or integer -> a finite positive float, else None."""
    try:
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return number if math.isfinite(number) and number > 0 else None


def exif_focal(data: bytes, size: tuple[int, int]) -> float | None:
    """Encoded image bytes and its size (W, H) in pixels after EXIF orientation -> the
    camera's focal length fx in pixels of that image from its EXIF 35 mm equivalent (module
    docstring), or None where the tags give none that can be used."""
    try:
        with Image.open(io.BytesIO(data)) as image:
            tags = image.getexif().get_ifd(IFD.Exif)
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError, struct.error):
        return None
    f35 = _number(tags.get(Base.FocalLengthIn35mmFilm))
    if f35 is None or not F35_RANGE_MM[0] <= f35 <= F35_RANGE_MM[1]:
        return None
    exif_w, exif_h = _number(tags.get(Base.ExifImageWidth)), _number(tags.get(Base.ExifImageHeight))
    if exif_w is not None and exif_h is not None:  # either orientation: compare long / short
        aspect, exif_aspect = max(size) / min(size), max(exif_w, exif_h) / min(exif_w, exif_h)
        if abs(aspect / exif_aspect - 1) > ASPECT_TOLERANCE:
            return None
    return f35 * math.hypot(*size) / FULL_FRAME_DIAGONAL_MM
