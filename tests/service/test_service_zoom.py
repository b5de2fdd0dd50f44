"""service.pipeline.zoom: the tiles, their frame mapping, and the zoom pass on the shipped
default."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import cv2
import numpy as np
import pytest
from service_support import PHOTO

from service.core.paths import DEFAULT_MODEL
from service.core.preprocess import load_image, to_network_input
from service.pipeline.model import Answer, PoseModel
from service.pipeline.predictor import Predictor
from service.pipeline.zoom import (
    FILL,
    LARGE,
    MAX_ZOOM,
    closer_view,
    detail_of,
    search_order,
    tile_views,
    view_input,
    zoomed,
)
from service.settings import Settings

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


@pytest.mark.parametrize("view", [(80.0, 30.0, 0.5), (21.0, 7.0, 0.725)])
def test_an_enlarged_crop_keeps_the_pixel_centres(view: tuple[float, float, float]) -> None:
    """Input pixel (u, v) of the crop at view (u0, v0, s) is frame pixel
    (u0 + (u + 0.5) s - 0.5, ...): a linear ramp comes back as that ramp."""
    w, h = SIZE
    u, v = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    image = np.stack([u / w, v / h, np.zeros_like(u)])
    big = view_input(image, np.array(view, np.float32), None)
    assert big.shape == image.shape and big.dtype == np.float32
    want_u = (view[0] + (u + 0.5) * view[2] - 0.5) / w
    want_v = (view[1] + (v + 0.5) * view[2] - 0.5) / h
    inner = (slice(4, -4), slice(4, -4))  # bicubic borders replicate
    assert np.abs(big[0][inner] - want_u[inner]).max() * w < 0.1  # px
    assert np.abs(big[1][inner] - want_v[inner]).max() * h < 0.1


@pytest.mark.parametrize("view", [(80.0, 30.0, 0.5), (21.0, 7.0, 0.725)])
def test_a_crop_cut_from_the_upload_keeps_the_pixel_centres(
    view: tuple[float, float, float],
) -> None:
    """A 640x480 upload: the crop cut from its frame at 2x the input size puts each pixel's
    centre where the enlarged crop does (a linear ramp comes back as that ramp), sharper."""
    w0, h0 = 640, 480
    u, v = np.meshgrid(np.arange(w0, dtype=np.float32), np.arange(h0, dtype=np.float32))
    upload = np.stack([255 * (u + 0.5) / w0, 255 * (v + 0.5) / h0, np.zeros_like(u)], -1)
    detail = detail_of(upload, SIZE)
    assert detail is not None and detail.shape == (3, 240, 320) and detail.dtype == np.float32
    crop = view_input(to_network_input(upload, SIZE), np.array(view, np.float32), detail)
    assert crop.shape == (3, 120, 160)
    tu, tv = np.meshgrid(np.arange(160, dtype=np.float32), np.arange(120, dtype=np.float32))
    want_u = (view[0] + (tu + 0.5) * view[2]) / 160  # the frame's pixel centre, over its width
    want_v = (view[1] + (tv + 0.5) * view[2]) / 120
    # px of the frame, border included (area resampling over a fractional step: 0.05 px)
    assert np.abs(crop[0] - want_u).max() * 160 < 0.05
    assert np.abs(crop[1] - want_v).max() * 120 < 0.05


def test_only_uploads_of_twice_the_input_size_give_detail() -> None:
    assert detail_of(np.zeros((120, 160, 3), np.uint8), SIZE) is None  # the input's size
    assert detail_of(np.zeros((239, 640, 3), np.uint8), SIZE) is None  # too few rows
    portrait = detail_of(np.zeros((640, 480, 3), np.uint8), SIZE)  # turned to landscape
    assert portrait is not None and portrait.shape == (3, 240, 320)


def test_the_closer_view_is_filled_by_the_board_and_stays_in_the_frame() -> None:
    square = np.array([[0.0, 0.0], [64.0, 0.0], [64.0, 48.0], [0.0, 48.0]])
    u0, v0, s = closer_view(square * 1.5 + [40.0, 30.0], SIZE)  # type: ignore[misc]
    assert max(96 / (s * 160), 72 / (s * 120)) == pytest.approx(FILL, abs=0.03)
    assert (u0 + s * 80, v0 + s * 60) == pytest.approx((88.0, 66.0), abs=0.5)  # centred
    assert float(s * 160).is_integer() and float(s * 120).is_integer() and u0.is_integer()
    u0, v0, s = closer_view(square * 1.5 + [1.0, 70.0], SIZE)  # type: ignore[misc]
    assert u0 == 0 and v0 + s * 120 == 120  # kept inside the frame
    tiny = closer_view(square / 10 + [80.0, 60.0], SIZE)
    assert tiny is not None and tiny[2] == 1 / MAX_ZOOM
    assert closer_view(square * 2.5 * LARGE, SIZE) is None  # large: no second look
    assert closer_view(np.full((4, 2), np.nan), SIZE) is None


def _network_input() -> np.ndarray:
    """The test photo (a board filling most of it) as float32 [3, 120, 160] in [0, 1]."""
    return to_network_input(load_image(PHOTO, min_size=SIZE).rgb, SIZE)


def test_a_small_board_is_answered_from_its_crop(model: PoseModel) -> None:
    """The photo shrunk 2x into the centre of a grey frame: the zoom looks at the crop around
    it once, and its corners are the large board's, mapped to where the small one lies."""
    large = _network_input()
    big = model.run(large[None])
    assert big.probabilities[0, 0] < 0.5 and big.pattern is not None and big.pattern[0] > 0.5
    small = np.full_like(large, 0.5)
    small[:, 30:90, 40:120] = cv2.resize(
        large.transpose(1, 2, 0), (80, 60), interpolation=cv2.INTER_AREA
    ).transpose(2, 0, 1)
    whole = model.run(small[None])
    spy = Spy(model)
    answer = zoomed(spy, small[None], None)  # type: ignore[arg-type]
    assert [n for n, _ in spy.calls] == [1, 1]
    assert spy.calls[0][1] is None and whole.corners is not None
    assert np.array_equal(spy.calls[1][1], closer_view(whole.corners[0], SIZE)[None])
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


def test_a_zero_shot_model_searches_only_photos_with_more_pixels(model: PoseModel) -> None:
    """Its presence threshold is measured on whole frames: no board in a photo of the input's
    size, no second look at an enlarged tile of it (a trained model's search looks at one);
    a larger photo's tile has detail of its own, and is searched."""
    zero_shot = replace(model, card={**model.card, "zero_shot": {}})
    for (w, h), calls in (((160, 120), {"zero-shot": [1], "trained": [1, 1]}),
                          ((640, 480), {"zero-shot": [1, 1], "trained": [1, 1]})):  # fmt: skip
        blank = cv2.imencode(".png", np.full((h, w, 3), 128, np.uint8))[1].tobytes()
        for served in (zero_shot, model):
            spy = Spy(served)
            Predictor(spy, Settings()).predict([(None, blank)], "whole")  # type: ignore[arg-type]
            assert [n for n, _ in spy.calls] == calls[served.training], (w, served.training)


def test_the_service_cuts_the_tile_from_a_large_upload(model: PoseModel) -> None:
    """A 640x480 photo with a small board: the second look's input is the crop of the upload
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
    sharp = view_input(to_network_input(rgb, SIZE), view, detail_of(rgb, SIZE))
    assert np.allclose(spy.inputs[1][0], sharp, atol=1e-6)
    blurry = view_input(to_network_input(rgb, SIZE), view, None)
    assert not np.allclose(spy.inputs[1][0], blurry, atol=0.02)


class TwoLooks:
    """A stand-in graph: the whole frame finds a mid-sized board with pattern `first`, any
    crop answers class 8 with pattern `second`."""

    zooms, input_size = True, SIZE

    def __init__(self, first: float, second: float) -> None:
        self.first, self.second = first, second

    def run(
        self, batch: np.ndarray, aspect: Any = None, view: Any = None, focal: Any = None
    ) -> Answer:
        n = len(batch)
        corners = np.tile(
            np.array([[50.0, 40.0], [110.0, 40.0], [110.0, 80.0], [50.0, 80.0]]), (n, 1, 1)
        )
        probs = np.zeros((n, 9))
        probs[:, 1 if view is None else 8] = 1.0
        pattern = np.full(n, self.first if view is None else self.second)
        return Answer(probs, corners, pattern, None)


@pytest.mark.parametrize(("first", "second", "replaced"), [(0.6, 0.9, True), (0.9, 0.6, False)])
def test_a_crop_answers_only_where_it_reads_the_pattern_as_well(
    first: float, second: float, replaced: bool
) -> None:
    answer = zoomed(TwoLooks(first, second), np.zeros((1, 3, 120, 160), np.float32), None)  # type: ignore[arg-type]
    assert int(answer.probabilities[0].argmax()) == (8 if replaced else 1)
