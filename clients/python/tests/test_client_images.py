"""Image inputs: paths, bytes, file objects, numpy arrays (PNG via OpenCV or the stdlib), and
the local errors raised before any request is sent."""

from __future__ import annotations

import io
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from planar_pose_client import PoseClient, encode_png
from planar_pose_client.images import sniff_type, to_upload

REAL = Path(__file__).resolve().parents[3] / "train/assets/real/chessboard-stereo"


def _decode(png: bytes) -> np.ndarray:
    """PNG bytes -> uint8 pixels as stored (grey [H, W], RGB [H, W, 3] or RGBA [H, W, 4])."""
    pixels = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
    assert pixels is not None, "OpenCV cannot read the PNG"
    if pixels.ndim == 3:
        code = cv2.COLOR_BGR2RGB if pixels.shape[2] == 3 else cv2.COLOR_BGRA2RGBA
        pixels = cv2.cvtColor(pixels, code)
    return pixels


@pytest.fixture(params=["opencv", "stdlib"])
def png_writer(request, monkeypatch):
    """Run a test with OpenCV available to the SDK, and again with `import cv2` failing."""
    if request.param == "stdlib":
        monkeypatch.setitem(sys.modules, "cv2", None)
    return request.param


@pytest.mark.parametrize("shape", [(7, 5), (7, 5, 3), (7, 5, 4), (1, 1, 3)])
def test_arrays_become_lossless_png(png_writer, shape):
    rng = np.random.default_rng(sum(shape))
    pixels = rng.integers(0, 256, size=shape, dtype=np.uint8)
    png = encode_png(pixels)
    assert sniff_type(png) == ("image/png", "png")
    np.testing.assert_array_equal(_decode(png), pixels)


def test_a_real_photo_survives_the_stdlib_writer(png_writer):
    rgb = cv2.cvtColor(cv2.imread(str(REAL / "left03.jpg")), cv2.COLOR_BGR2RGB)
    view = rgb[::2, 1::2]  # not contiguous: the writer must still lay out rows correctly
    np.testing.assert_array_equal(_decode(encode_png(view)), view)


def test_uploads_are_named_and_typed():
    path = REAL / "left01.jpg"
    assert to_upload(path) == ("left01.jpg", path.read_bytes(), "image/jpeg")
    assert to_upload(str(path)).filename == "left01.jpg"
    assert to_upload(path.read_bytes(), 3)[::2] == ("image-3.jpg", "image/jpeg")
    with path.open("rb") as f:
        assert to_upload(f)[::2] == ("left01.jpg", "image/jpeg")
    assert to_upload(io.BytesIO(b"garbage"), 1)[::2] == ("image-1.bin", "application/octet-stream")
    assert to_upload(np.zeros((4, 4), np.uint8), 2)[::2] == ("array-2.png", "image/png")
    assert to_upload(b"GIF89a...", 4)[::2] == ("image-4.gif", "image/gif")


def test_the_content_type_comes_from_the_bytes_then_the_name(tmp_path):
    jpeg_named_txt = tmp_path / "photo.txt"
    jpeg_named_txt.write_bytes((REAL / "left01.jpg").read_bytes())
    notes, broken = tmp_path / "notes.txt", tmp_path / "broken.png"
    notes.write_text("hello")
    broken.write_bytes(b"truncated")
    assert to_upload(jpeg_named_txt).content_type == "image/jpeg"
    assert to_upload(notes).content_type == "text/plain"
    assert to_upload(broken).content_type == "image/png"


def test_bad_inputs_fail_before_any_request(tmp_path):
    text_file = tmp_path / "notes.txt"
    text_file.write_text("hello")
    (tmp_path / "empty.png").write_bytes(b"")
    cases = [
        (tmp_path / "missing.jpg", FileNotFoundError, "no such image file"),
        (tmp_path, IsADirectoryError, "is a directory"),
        (tmp_path / "empty.png", ValueError, "empty"),
        (b"", ValueError, "empty"),
        (12, TypeError, "unsupported type int"),
        (text_file.open("r"), TypeError, "text mode"),
        (np.zeros((4, 4), np.float32), ValueError, "uint8"),
        (np.zeros((4, 4, 2), np.uint8), ValueError, r"got shape \(4, 4, 2\)"),
        (np.zeros((0, 4), np.uint8), ValueError, "H, W > 0"),
    ]
    # Nothing listens on port 9 (discard): a request would raise PoseConnectionError instead.
    with PoseClient("http://127.0.0.1:9", retries=0) as client:
        for image, error, message in cases:
            with pytest.raises(error, match=message):
                client.predict(image)
        for not_a_list in (str(REAL / "left01.jpg"), b"\xff\xd8\xff", np.zeros((4, 4), np.uint8)):
            with pytest.raises(TypeError, match="use predict for one image"):
                client.predict_many(not_a_list)
        with pytest.raises(ValueError, match="at least one image"):
            client.predict_many([])
        for fx in (0.0, -3.0, float("nan"), float("inf")):
            with pytest.raises(ValueError, match="fx must be a positive number of pixels"):
                client.predict(b"\xff\xd8\xff", fx=fx)


@pytest.mark.parametrize("url", ["127.0.0.1:8000", "ftp://host", "http://"])
def test_a_base_url_without_scheme_or_host_is_refused(url):
    with pytest.raises(ValueError, match="base_url must look like"):
        PoseClient(url)


def test_the_sdk_does_not_need_numpy():
    code = (
        "import sys\n"
        "from planar_pose_client import PoseClient\n"
        "from planar_pose_client.images import to_upload\n"
        f"to_upload({str(REAL / 'left01.jpg')!r}); to_upload(b'\\xff\\xd8\\xff')\n"
        "PoseClient().close()\n"
        "print(sorted({'numpy', 'cv2'} & set(sys.modules)))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"
