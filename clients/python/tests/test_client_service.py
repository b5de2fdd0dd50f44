"""Every method of both clients against the real service, with auth off and on, and every error
status produced for real and mapped to its exception."""

from __future__ import annotations

import asyncio
import io
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
from live_service import API_KEY, DEFAULT_NAME, OTHER_MODEL
from planar_pose_client import (
    AsyncPoseClient,
    AuthError,
    BadImageError,
    InvalidRequestError,
    ModelCard,
    ModelNotFoundError,
    PoseClient,
    Prediction,
    ServiceUnavailable,
    TooLargeError,
)

# The region of each class in words (docs/SPEC.md section 3), written out independently.
LABELS = ["object not in view"] + [
    f"{depth}, x{x}, y{y}"
    for depth in ("near", "far")
    for x, y in (("+", "+"), ("-", "+"), ("-", "-"), ("+", "-"))
]


def check_prediction(p: Prediction, filename: str | None) -> None:
    """A prediction is internally consistent: label of its class, confidence = top probability."""
    assert p.filename == filename
    assert p.label == LABELS[p.class_id] and p.present == (p.class_id != 0)
    assert (p.region.depth is None) == (p.class_id == 0)
    assert abs(sum(p.probabilities) - 1.0) < 1e-4
    assert p.probabilities[p.class_id] == max(p.probabilities)
    assert p.confidence == pytest.approx(p.probabilities[p.class_id], abs=1e-6)
    assert p.elapsed_ms >= 0.0
    assert p.corners is None or (p.present and len(p.corners) == 4)


def check_card(card: ModelCard) -> None:
    assert card.name and card.version
    assert len(card.input) == 2 and all(n > 0 for n in card.input)
    assert len(card.classes) == 9


def huge_header_png(width: int = 50_000, height: int = 50_000) -> bytes:
    """A valid-looking 1 kB PNG whose header claims width x height RGB pixels (a
    decompression bomb): the service must refuse it from the header, not decode it."""

    def chunk(kind: bytes, body: bytes) -> bytes:
        return (
            struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
        )

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    rows = zlib.compress(b"\x00" * (1 + 3 * width) * 4)
    return (
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", rows) + chunk(b"IEND", b"")
    )


def test_sync_client_every_method(service_url, photos):
    with PoseClient(service_url) as client:
        assert client.health() and client.ready()
        check_card(client.model_info())
        one = client.predict(photos[0])
        check_prediction(one, photos[0].name)
        assert one.box is None
        assert one.corners is not None  # the default model reports the board's corners
        many = client.predict_many(photos)
    assert [p.filename for p in many] == [p.name for p in photos]
    for p in many:
        check_prediction(p, p.filename)
    # batch sizes round differently in onnxruntime; the alignment's steps carry it (1e-4 seen)
    np.testing.assert_allclose(many[0].probabilities, one.probabilities, atol=1e-3)


def test_a_known_focal_length_reaches_the_service(service_url, photos):
    """`fx` goes with the request: through a lens 3x longer than the camera's the board is
    farther (the far classes 5-8 gain probability), the corners unchanged; mode=sliding
    refuses it (422)."""
    with PoseClient(service_url) as client:
        plain = client.predict(photos[0])
        long_lens = client.predict(photos[0], fx=1600.0)
        assert sum(long_lens.probabilities[5:]) > sum(plain.probabilities[5:]) + 0.1
        assert long_lens.corners == plain.corners
        assert (plain.fx, plain.fx_source) == (None, None)  # the corpus photos have no EXIF
        assert (long_lens.fx, long_lens.fx_source) == (1600.0, "query")
        with pytest.raises(InvalidRequestError, match="fx: applies to mode=whole only"):
            client.predict(photos[0], mode="sliding", fx=1600.0)


def test_every_kind_of_image_input_gives_the_same_answer(service_url, photos):
    path = photos[1]
    rgb = cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)
    with PoseClient(service_url) as client, path.open("rb") as file:
        by_path = client.predict(path)
        others = client.predict_many([str(path), path.read_bytes(), file, rgb, rgb[:, :, 0]])
    assert [p.filename for p in others] == [
        path.name,
        "image-1.jpg",
        path.name,
        "array-3.png",
        "array-4.png",
    ]
    for p in others[:3]:  # the same bytes (in a batch: onnxruntime's rounding, 1e-4 seen)
        np.testing.assert_allclose(p.probabilities, by_path.probabilities, atol=1e-3)
    for p in others[3:]:  # the same pixels; the service may decode a JPEG at reduced scale
        assert p.class_id == by_path.class_id
        np.testing.assert_allclose(p.probabilities, by_path.probabilities, atol=1e-3)


def test_sliding_mode_returns_a_box_inside_the_image(service_url, photos):
    with PoseClient(service_url) as client:
        predictions = client.predict_many(photos[:2], mode="sliding")
    for p in predictions:
        check_prediction(p, p.filename)
        assert p.corners is None  # whole mode only
        if p.present:
            assert p.box is not None
            assert p.box.x >= 0 and p.box.y >= 0 and p.box.w > 0 and p.box.h > 0
            assert p.box.x + p.box.w <= 640 and p.box.y + p.box.h <= 480


def test_async_client_every_method(service_url, photos):
    async def run():
        async with AsyncPoseClient(service_url) as client:
            alive, ready, card = await asyncio.gather(
                client.health(), client.ready(), client.model_info()
            )
            singles = await asyncio.gather(*(client.predict(p) for p in photos))
            many = await client.predict_many(photos, mode="whole")
            return alive, ready, card, singles, many

    alive, ready, card, singles, many = asyncio.run(run())
    assert alive and ready
    check_card(card)
    for single, batched, path in zip(singles, many, photos, strict=True):
        check_prediction(single, path.name)
        # batch sizes round differently in onnxruntime; the alignment's steps carry it
        np.testing.assert_allclose(single.probabilities, batched.probabilities, atol=1e-3)
    with PoseClient(service_url) as client:
        assert client.model_info() == card


def test_errors_map_to_exceptions(service_url, photos):
    with PoseClient(service_url, retries=0) as client:
        with pytest.raises(BadImageError) as bad:
            client.predict(b"this is not an image at all")
        assert bad.value.status == 400 and bad.value.code and bad.value.message
        assert str(bad.value).startswith("HTTP 400 ")

        with pytest.raises(InvalidRequestError) as invalid:
            client.predict(photos[0], mode="diagonal")  # type: ignore[arg-type]
        assert invalid.value.status == 422

        with pytest.raises(TooLargeError) as bomb:
            client.predict(io.BytesIO(huge_header_png()))
        assert bomb.value.status == 413


def test_too_many_images_is_refused(service_url, photos):
    with PoseClient(service_url, retries=0) as client, pytest.raises(TooLargeError) as too_many:
        client.predict_many(photos[:1] * 200)
    assert too_many.value.status == 413


def test_auth_on(secured_url, photos):
    with PoseClient(secured_url, retries=0) as anonymous:
        assert anonymous.health()  # probes stay open for orchestrators
        with pytest.raises(AuthError) as missing:
            anonymous.predict(photos[0])
        assert missing.value.status == 401
        with pytest.raises(AuthError):
            anonymous.model_info()
    with PoseClient(secured_url, api_key="wrong", retries=0) as wrong, pytest.raises(AuthError):
        wrong.predict(photos[0])
    with PoseClient(secured_url, api_key=API_KEY) as client:
        check_card(client.model_info())
        check_prediction(client.predict(photos[0]), photos[0].name)

    async def run_async():
        async with AsyncPoseClient(secured_url, api_key="wrong", retries=0) as wrong_async:
            with pytest.raises(AuthError):
                await wrong_async.predict(photos[0])
        async with AsyncPoseClient(secured_url, api_key=API_KEY) as right_async:
            return await right_async.predict_many(photos)

    assert len(asyncio.run(run_async())) == len(photos)


def test_the_same_photo_as_a_path_file_gives_its_own_name(service_url, tmp_path: Path, photos):
    copy = tmp_path / "renamed photo.jpg"
    copy.write_bytes(photos[0].read_bytes())
    with PoseClient(service_url) as client:
        assert client.predict(copy).filename == "renamed photo.jpg"


def test_a_service_that_is_not_ready(unready_url, photos):
    with PoseClient(unready_url, retries=1, backoff=0.01) as client:
        assert client.health() and not client.ready()
        with pytest.raises(ServiceUnavailable) as info:
            client.predict(photos[0])
    assert info.value.status == 503 and info.value.code == "not_ready"
    assert "model not loaded" in info.value.message

    async def run():
        async with AsyncPoseClient(unready_url, retries=0) as client:
            assert await client.health() and not await client.ready()
            await client.model_info()

    with pytest.raises(ServiceUnavailable):
        asyncio.run(run())


def test_models_and_choosing_one_per_request(folder_url, photos):
    with PoseClient(folder_url, retries=0) as client:
        listing = client.models()
        names = {m.name for m in listing.models}
        assert listing.default == DEFAULT_NAME and {DEFAULT_NAME, OTHER_MODEL} <= names
        large = next(m for m in listing.models if m.name == OTHER_MODEL)
        assert len(large.input) == 2 and large.profile == "chessboard" and not large.default
        assert large.training == "trained"
        default = client.predict(photos[0])
        other = client.predict(photos[0], model=OTHER_MODEL)
        check_prediction(other, photos[0].name)
        assert other.probabilities != default.probabilities
        many = client.predict_many(photos, mode="sliding", model=OTHER_MODEL)
        assert [p.filename for p in many] == [p.name for p in photos]
        with pytest.raises(ModelNotFoundError) as unknown:
            client.predict(photos[0], model="nope")
        assert unknown.value.status == 404 and OTHER_MODEL in unknown.value.message
        with pytest.raises(ValueError, match="not a model name"):
            client.predict(photos[0], model="../v1/model")

    async def run():
        async with AsyncPoseClient(folder_url) as client:
            return await client.models(), await client.predict(photos[0], model="default")

    listing_async, again = asyncio.run(run())
    assert listing_async == listing
    np.testing.assert_allclose(again.probabilities, default.probabilities, atol=1e-6)
