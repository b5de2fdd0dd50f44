"""The focal length from a photo's EXIF tags (service/pipeline/exif.py): the 35 mm equivalent
over the diagonal, either orientation, crops and absurd or broken tags ignored."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from image_bytes import with_exif_focal, with_exif_orientation

from service.pipeline.exif import exif_focal

PHOTO = cv2.imencode(".png", np.full((48, 64, 3), 90, np.uint8))[1].tobytes()
JPEG = cv2.imencode(".jpg", np.full((48, 64, 3), 90, np.uint8))[1].tobytes()
PHONE = (4032, 3024)  # a phone's 4:3 frame
F26 = 26 * math.hypot(640, 480) / math.hypot(36, 24)  # fx of a 26 mm equivalent at 640x480


@pytest.mark.parametrize(
    ("fmt", "exif_size", "size", "fx"),
    [
        ("PNG", PHONE, (640, 480), F26),  # downscaled: same angle of view
        ("JPEG", PHONE, (480, 640), F26),  # a portrait (EXIF turned): the same diagonal
        ("WEBP", None, (640, 480), F26),  # no pixel size in the tags: taken as the frame
        ("PNG", PHONE, (4032, 3024), F26 * 6.3),
        ("PNG", PHONE, (640, 360), None),  # 16:9 out of a 4:3 frame: a crop
    ],
)
def test_the_35mm_equivalent_gives_fx_in_pixels_of_the_upload(
    fmt: str, exif_size: tuple[int, int] | None, size: tuple[int, int], fx: float | None
) -> None:
    found = exif_focal(with_exif_focal(PHOTO, 26, exif_size, fmt), size)
    if fx is None:
        assert found is None
    else:
        assert found == pytest.approx(fx, rel=1e-6)


@pytest.mark.parametrize(
    "data",
    [
        PHOTO,  # no EXIF
        with_exif_orientation(JPEG, 6),
        with_exif_focal(PHOTO, 0),  # "unknown" in the EXIF standard
        with_exif_focal(PHOTO, 5000),  # no lens
        b"\xff\xd8\xff\xe1\x00\x10Exif\x00\x00II*\x00\xff\xff\xff\x7f\xff\xd9",  # broken IFD
        b"not an image",
    ],
    ids=["no-exif", "orientation-only", "zero", "absurd", "broken", "garbage"],
)
def test_photos_without_a_usable_focal_length_give_none(data: bytes) -> None:
    assert exif_focal(data, (64, 48)) is None
