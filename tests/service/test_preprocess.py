"""service.core.preprocess: header guard, formats, EXIF orientation, reduced decoding, fuzzing."""

from __future__ import annotations

import struct

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from image_bytes import png_claiming, with_exif_orientation
from service_support import REAL

from service.core.preprocess import (
    ImageDecodeError,
    ImageTooLargeError,
    NetworkFrame,
    decode_image,
    image_header,
    load_image,
    resize_rgb,
    to_network_input,
)

PHOTO = (REAL / "left01.jpg").read_bytes()


def encode(ext: str, image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(ext, image)
    assert ok
    return buf.tobytes()


def colour_image(w: int = 64, h: int = 48) -> np.ndarray:
    """BGR uint8 with a distinct colour per quadrant (so orientation and channels are visible)."""
    img = np.zeros((h, w, 3), np.uint8)
    img[: h // 2, : w // 2] = (0, 0, 255)  # red top left
    img[: h // 2, w // 2 :] = (0, 255, 0)  # green top right
    img[h // 2 :, : w // 2] = (255, 0, 0)  # blue bottom left
    return img


def jpeg_claiming(w: int, h: int) -> bytes:
    """A real JPEG whose SOF0 says w x h."""
    data = bytearray(encode(".jpg", colour_image()))
    sof = data.index(b"\xff\xc0")
    data[sof + 5 : sof + 9] = struct.pack(">HH", h, w)
    return bytes(data)


@pytest.mark.parametrize("ext", [".png", ".jpg", ".webp", ".bmp", ".gif"])
def test_header_matches_decoded_size(ext: str) -> None:
    data = encode(ext, colour_image(70, 33))
    header = image_header(data)
    assert (header.width, header.height) == (70, 33)
    rgb = decode_image(data)
    assert rgb.shape == (33, 70, 3) and rgb.dtype == np.uint8


def test_lossy_webp_header() -> None:
    ok, buf = cv2.imencode(".webp", colour_image(70, 33), [cv2.IMWRITE_WEBP_QUALITY, 80])
    assert ok and buf.tobytes()[12:16] == b"VP8 "
    assert image_header(buf.tobytes()).width == 70


def test_colours_come_out_rgb() -> None:
    rgb = decode_image(encode(".png", colour_image()))
    assert tuple(rgb[0, 0]) == (255, 0, 0) and tuple(rgb[0, -1]) == (0, 255, 0)


@pytest.mark.parametrize(
    ("data", "what"),
    [
        (png_claiming(50_000, 50_000), "png"),
        (jpeg_claiming(60_000, 60_000), "jpeg"),
        (b"RIFF\0\0\0\0WEBPVP8X" + bytes(8) + (59_999).to_bytes(3, "little") * 2, "webp"),
        (b"BM" + bytes(12) + struct.pack("<Iii", 40, 40_000, -40_000), "bmp"),
        (b"GIF89a" + struct.pack("<HH", 65_535, 65_535), "gif"),
    ],
)
def test_decompression_bombs_refused_from_the_header(data: bytes, what: str) -> None:
    assert image_header(data).format == what
    with pytest.raises(ImageTooLargeError, match="more than the limit"):
        load_image(data, max_pixels=50_000_000)


def test_pixel_limit_is_inclusive() -> None:
    data = encode(".png", colour_image(40, 30))
    assert decode_image(data, max_pixels=1200).shape == (30, 40, 3)
    with pytest.raises(ImageTooLargeError):
        decode_image(data, max_pixels=1199)


@pytest.mark.parametrize(
    "data",
    [b"", b"hello world", PHOTO[: len(PHOTO) // 2], PHOTO[:200], png_claiming(10, 10), b"BM\0"],
    ids=["empty", "text", "truncated-jpeg", "jpeg-headers-only", "png-without-data", "short-bmp"],
)
def test_bad_bytes_raise_decode_error(data: bytes) -> None:
    with pytest.raises(ImageDecodeError):
        decode_image(data)


def test_grey_rgba_16bit_become_rgb8() -> None:
    grey = np.full((20, 30), 77, np.uint8)
    rgba = np.dstack([colour_image(30, 20), np.full((20, 30), 128, np.uint8)])
    deep = np.full((20, 30), 40_000, np.uint16)
    for image, value in ((grey, 77), (rgba, 255), (deep, 40_000 >> 8)):
        rgb = decode_image(encode(".png", image))
        assert rgb.shape == (20, 30, 3) and rgb.dtype == np.uint8
        assert rgb.max() == value


@pytest.mark.parametrize("min_size", [None, (80, 60)])
def test_exif_orientation_applied_also_when_reduced(min_size: tuple[int, int] | None) -> None:
    plain = encode(".jpg", cv2.resize(colour_image(), (1280, 960), interpolation=cv2.INTER_NEAREST))
    turned = with_exif_orientation(plain, 6)  # 6 = rotate 90 degrees clockwise to display
    a, b = load_image(plain, min_size=min_size), load_image(turned, min_size=min_size)
    assert (a.width, a.height) == (1280, 960) and (b.width, b.height) == (960, 1280)
    assert np.array_equal(b.rgb, np.rot90(a.rgb, k=-1))


def test_large_jpeg_decoded_at_reduced_scale_but_never_below_need() -> None:
    data = encode(".jpg", cv2.resize(colour_image(), (1280, 960)))
    assert load_image(data, min_size=(80, 60)).rgb.shape == (120, 160, 3)  # 1/8: 120 >= 80
    assert load_image(data, min_size=(160, 120)).rgb.shape == (240, 320, 3)  # 1/4
    assert load_image(data, min_size=(1000, 750)).rgb.shape == (960, 1280, 3)
    assert load_image(PHOTO, min_size=(80, 60)).rgb.shape == (120, 160, 3)


def test_to_network_input_shape_range_and_resize() -> None:
    rgb = decode_image(PHOTO)
    x = to_network_input(rgb, (80, 60))
    assert x.shape == (3, 60, 80) and x.dtype == np.float32
    assert x.min() >= 0.0 and x.max() <= 1.0
    assert resize_rgb(np.zeros((1, 1, 3), np.uint8), (80, 60)).shape == (60, 80, 3)


@pytest.mark.parametrize(
    ("image", "turned", "aspect"),
    [((640, 480), False, 1.0), ((1280, 720), False, 4 / 3), ((480, 640), True, 1.0),
     ((640, 640), False, 0.75), ((360, 640), True, 4 / 3)],
)  # fmt: skip
def test_network_frame_turns_portraits_and_says_the_pixel_aspect(image, turned, aspect) -> None:
    frame = NetworkFrame(image, (160, 120))
    assert frame.turned is turned and frame.pixel_aspect == pytest.approx(aspect)
    w, h = image
    uv = np.array([[0.0, 0.0], [w - 1, 0], [w - 1, h - 1], [0, h - 1], [w / 3, h / 5]])
    assert np.allclose(frame.to_image(frame.to_network(uv)), uv)
    rgb = np.zeros((h, w, 3), np.uint8)
    rgb[0, 0] = 255  # the top-left pixel: top right of the input once turned clockwise
    x = frame.input_of(rgb)
    assert x.shape == (120, 160, 3)
    corner = frame.to_network(np.array([0.0, 0.0]))
    assert np.allclose(
        corner, [159.5 - 80 / h, -0.5 + 60 / w] if turned else [-0.5 + 80 / w, -0.5 + 60 / h]
    )
    assert x[:2, -2:].any() if turned else x[:2, :2].any()
    assert np.array_equal(to_network_input(rgb, (160, 120)), x.transpose(2, 0, 1) / np.float32(255))


def _decode_cleanly(data: bytes) -> None:
    """Both entry points return RGB uint8 or raise ImageDecodeError, nothing else."""
    for decode in (
        decode_image,
        lambda d: load_image(d, max_pixels=4_000_000, min_size=(80, 60)).rgb,
    ):
        try:
            rgb = decode(data)
        except ImageDecodeError:
            continue
        assert rgb.ndim == 3 and rgb.shape[2] == 3 and rgb.dtype == np.uint8


MAGICS = [b"", b"\x89PNG\r\n\x1a\n", b"\xff\xd8", b"RIFF\0\0\0\0WEBP", b"BM", b"GIF89a"]


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(MAGICS), st.binary(max_size=512))
def test_random_bytes_only_ever_raise_decode_error(magic: bytes, tail: bytes) -> None:
    _decode_cleanly(magic + tail)


SMALL = [encode(ext, colour_image(16, 12)) for ext in (".png", ".jpg", ".webp", ".bmp", ".gif")]


@settings(max_examples=300, deadline=None)
@given(
    st.sampled_from(SMALL),
    st.lists(st.tuples(st.integers(0, 10_000), st.integers(0, 255)), min_size=1, max_size=8),
    st.integers(0, 10_000),
)
def test_corrupted_images_only_ever_raise_decode_error(
    data: bytes, flips: list[tuple[int, int]], cut: int
) -> None:
    corrupted = bytearray(data)
    for at, value in flips:
        corrupted[at % len(corrupted)] = value
    _decode_cleanly(bytes(corrupted[: max(1, len(corrupted) - cut % len(corrupted))]))
