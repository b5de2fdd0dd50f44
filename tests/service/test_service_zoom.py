"""service.zoom: the tiles, their frame mapping, and the zoom pass on the shipped default."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import pytest
from service_support import PHOTO

from service.core.preprocess import load_image, to_network_input
from service.model import Answer, PoseModel
from service.predictor import Predictor
from service.settings import DEFAULT_MODEL, Settings
from service.zoom import (
    MARGIN_PX,
    detail_of,
    enlarged,
    holding_tile,
    search_order,
    tile_input,
    tile_views,
    zoomed,
)

SIZE = (160, 120)


@pytest.fixture(scope="module")
def model() -> PoseModel:
    loaded = PoseModel.load(DEFAULT_MODEL)
    assert loaded.zooms and loaded.input_size == SIZE  # the shipped default serves the zoom
    return loaded


class Spy:
    """A `PoseModel` whose `run` calls are recorded as (N, view), their inputs in `inputs`."""

    def __init__(self, model: PoseModel) -> None:
        self.model, self.calls, self.inputs = model, [], []

    def __getattr__(self, name: str) -> Any:
        return getattr(self.model, name)

    def run(
        self, batch: np.ndarray, aspect: Any = None, view: Any = None, focal: Any = None
    ) -> Answer:
        self.calls.append((len(batch), None if view is None else np.array(view)))
        self.inputs.append(batch)
        return self.model.run(batch, aspect, view, focal)


def test_the_tiles_are_half_size_and_cover_the_input() -> None:
    views = tile_views(SIZE)
    assert views.shape == (9, 3) and np.all(views[:, 2] == 0.5)
    assert {tuple(v) for v in views[:, :2]} == {(u, v) for u in (0, 40, 80) for v in (0, 30, 60)}
    assert views[4, :2].tolist() == [40.0, 30.0]  # the centre tile


def test_an_enlarged_tile_keeps_the_pixel_centres() -> None:
    """Input pixel (u, v) of the enlarged tile at (u0, v0) is frame pixel
    (u0 + (u + 0.5) / 2 - 0.5, ...): a linear ramp comes back as that ramp."""
    w, h = SIZE
    u, v = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    image = np.stack([u / w, v / h, np.zeros_like(u)])
    view = tile_views(SIZE)[5]  # (80, 30)
    big = enlarged(image, view)
    assert big.shape == image.shape and big.dtype == np.float32
    want_u = (view[0] + (u + 0.5) * 0.5 - 0.5) / w
    want_v = (view[1] + (v + 0.5) * 0.5 - 0.5) / h
    inner = (slice(4, -4), slice(4, -4))  # bicubic borders replicate
    assert np.abs(big[0][inner] - want_u[inner]).max() * w < 0.1  # px
    assert np.abs(big[1][inner] - want_v[inner]).max() * h < 0.1


def test_a_tile_cut_from_the_upload_keeps_the_pixel_centres() -> None:
    """A 640x480 upload: the tile cut from its frame at 2x the input size puts each pixel's
    centre where the enlarged tile does (a linear ramp comes back as that ramp), sharper."""
    w0, h0 = 640, 480
    u, v = np.meshgrid(np.arange(w0, dtype=np.float32), np.arange(h0, dtype=np.float32))
    upload = np.stack([255 * (u + 0.5) / w0, 255 * (v + 0.5) / h0, np.zeros_like(u)], -1)
    detail = detail_of(upload, SIZE)
    assert detail is not None and detail.shape == (3, 240, 320) and detail.dtype == np.float32
    view = tile_views(SIZE)[5]  # (80, 30)
    tile = tile_input(to_network_input(upload, SIZE), view, detail)
    assert tile.shape == (3, 120, 160)
    tu, tv = np.meshgrid(np.arange(160, dtype=np.float32), np.arange(120, dtype=np.float32))
    want_u = (view[0] + (tu + 0.5) * 0.5) / 160  # the frame's pixel centre, over its width
    want_v = (view[1] + (tv + 0.5) * 0.5) / 120
    assert np.abs(tile[0] - want_u).max() * 160 < 0.01  # px of the frame, border included
    assert np.abs(tile[1] - want_v).max() * 120 < 0.01


def test_only_uploads_of_twice_the_input_size_give_detail() -> None:
    assert detail_of(np.zeros((120, 160, 3), np.uint8), SIZE) is None  # the input's size
    assert detail_of(np.zeros((239, 640, 3), np.uint8), SIZE) is None  # too few rows
    portrait = detail_of(np.zeros((640, 480, 3), np.uint8), SIZE)  # turned to landscape
    assert portrait is not None and portrait.shape == (3, 240, 320)
    image = np.zeros((3, 120, 160), np.float32)
    view = tile_views(SIZE)[0]
    assert np.array_equal(tile_input(image, view, None), enlarged(image, view))


def test_the_holding_tile_is_the_nearest_centred_one_with_margin() -> None:
    views = tile_views(SIZE)
    square = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]])
    assert holding_tile(square + [75.0, 55.0], views, SIZE) == 4  # centred on the input
    assert holding_tile(square + [MARGIN_PX + 1, MARGIN_PX + 1], views, SIZE) == 0
    assert holding_tile(square + [MARGIN_PX - 1, 20.0], views, SIZE) is None  # too near the edge
    assert holding_tile(square * 9 + [5.0, 5.0], views, SIZE) is None  # wider than a tile


def _network_input() -> np.ndarray:
    """The test photo (a board filling most of it) as float32 [3, 120, 160] in [0, 1]."""
    return to_network_input(load_image(PHOTO, min_size=SIZE).rgb, SIZE)


def test_a_small_board_is_answered_from_its_tile(model: PoseModel) -> None:
    """The photo shrunk 2x into the centre tile of a grey frame: the zoom looks at that tile
    once, and its corners are the large board's, mapped to where the small one lies."""
    large = _network_input()
    big = model.run(large[None])
    assert big.probabilities[0, 0] < 0.5 and big.pattern is not None and big.pattern[0] > 0.5
    small = np.full_like(large, 0.5)
    small[:, 30:90, 40:120] = cv2.resize(
        large.transpose(1, 2, 0), (80, 60), interpolation=cv2.INTER_AREA
    ).transpose(2, 0, 1)
    spy = Spy(model)
    answer = zoomed(spy, small[None], None)  # type: ignore[arg-type]
    assert [n for n, _ in spy.calls] == [1, 1]
    assert spy.calls[0][1] is None and spy.calls[1][1].tolist() == [[40.0, 30.0, 0.5]]
    assert answer.pattern is not None and answer.pattern[0] >= 0.5
    assert answer.probabilities[0, 0] < 0.5
    assert big.corners is not None and answer.corners is not None
    want = np.array([40.0, 30.0]) + (big.corners[0] + 0.5) * 0.5 - 0.5  # INTER_AREA's centres
    assert np.abs(answer.corners[0] - want).max() < 1.5  # px of the frame


def test_no_board_looks_at_the_guessed_tile_and_stays_absent(model: PoseModel) -> None:
    rng = np.random.default_rng(3)
    smooth = cv2.GaussianBlur(rng.random((120, 160, 3), dtype=np.float32), (0, 0), 6)
    batch = np.stack([smooth.transpose(2, 0, 1), np.full((3, 120, 160), 0.4, np.float32)])
    whole = model.run(batch)
    assert whole.corners is not None and np.all(whole.probabilities[:, 0] > 0.5)
    spy = Spy(model)
    answer = zoomed(spy, batch, np.ones(2, np.float32))  # type: ignore[arg-type]
    assert [n for n, _ in spy.calls] == [2, 2]  # one tile of each image, one run
    views = tile_views(SIZE)
    guessed = [views[search_order(c, views, SIZE)[0]] for c in whole.corners]
    assert np.array_equal(spy.calls[1][1], np.stack(guessed))  # nearest the corners' guess
    assert np.all(answer.probabilities[:, 0] > 0.5)
    spy = Spy(model)
    everywhere = zoomed(spy, batch, np.ones(2, np.float32), search_tiles=9)  # type: ignore[arg-type]
    assert [n for n, _ in spy.calls] == [2, 18]  # every tile of both images, one run
    assert np.all(everywhere.probabilities[:, 0] > 0.5)
    with pytest.raises(ValueError, match="search_tiles"):
        zoomed(spy, batch, None, search_tiles=10)  # type: ignore[arg-type]
    spy = Spy(model)
    unsearched = zoomed(spy, batch, np.ones(2, np.float32), search=False)  # type: ignore[arg-type]
    assert [n for n, _ in spy.calls] == [2]  # the whole frames only
    assert np.allclose(unsearched.probabilities, model.run(batch).probabilities, atol=1e-6)


def test_a_model_without_the_view_input_answers_the_whole_frame() -> None:
    old = PoseModel.load(DEFAULT_MODEL.with_name("chessboard-spec-160x120.onnx"))
    assert not old.zooms
    batch = np.full((2, 3, 120, 160), 0.3, np.float32)
    spy = Spy(old)
    answer = zoomed(spy, batch, None)  # type: ignore[arg-type]
    assert len(spy.calls) == 1 and np.allclose(answer.probabilities, old.predict(batch))


def test_the_zoom_setting_switches_the_pass_off(model: PoseModel) -> None:
    photo = cv2.imdecode(np.frombuffer(PHOTO, np.uint8), cv2.IMREAD_COLOR)
    frame = np.full((120, 160, 3), 128, np.uint8)
    frame[30:90, 40:120] = cv2.resize(photo, (80, 60), interpolation=cv2.INTER_AREA)
    ok, png = cv2.imencode(".png", frame)
    assert ok
    runs = {}
    for zoom in (True, False):
        spy = Spy(model)
        predictor = Predictor(spy, Settings(zoom=zoom))  # type: ignore[arg-type]
        predictor.predict([(None, png.tobytes())], "whole")
        runs[zoom] = len(spy.calls)
    assert runs == {True: 2, False: 1}
    # no board in view: the search's tiles (1 by default, POSE_ZOOM_SEARCH_TILES), or none
    blank = cv2.imencode(".png", np.full((120, 160, 3), 128, np.uint8))[1].tobytes()
    for options, calls in (
        ({}, [1, 1]),
        ({"zoom_search_tiles": 9}, [1, 9]),
        ({"zoom_search": False}, [1]),
    ):
        spy = Spy(model)
        Predictor(spy, Settings(**options)).predict([(None, blank)], "whole")  # type: ignore[arg-type]
        assert [n for n, _ in spy.calls] == calls


def test_the_service_cuts_the_tile_from_a_large_upload(model: PoseModel) -> None:
    """A 640x480 photo with a small board: the second look's input is the tile of the upload
    at 2x the input size, not the enlarged network input."""
    photo = cv2.imdecode(np.frombuffer(PHOTO, np.uint8), cv2.IMREAD_COLOR)
    frame = np.full((480, 640, 3), 128, np.uint8)
    frame[120:360, 160:480] = cv2.resize(photo, (320, 240), interpolation=cv2.INTER_AREA)
    png = cv2.imencode(".png", frame)[1].tobytes()
    spy = Spy(model)
    result = Predictor(spy, Settings()).predict([(None, png)], "whole").results[0]  # type: ignore[arg-type]
    assert [n for n, _ in spy.calls] == [1, 1] and result.class_id != 0
    rgb = cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)
    view = spy.calls[1][1][0]
    sharp = tile_input(to_network_input(rgb, SIZE), view, detail_of(rgb, SIZE))
    assert np.allclose(spy.inputs[1][0], sharp, atol=1e-6)
    assert not np.allclose(spy.inputs[1][0], enlarged(to_network_input(rgb, SIZE), view), atol=0.02)
