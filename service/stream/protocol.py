"""The live stream behind `WS /v1/stream`: frames in, one answer per frame out, in order.

The client sends each frame as one binary message (JPEG or PNG bytes); the server answers each
with the per-image JSON of `/v1/predict` plus `seq` (0-based index of the binary message on
this socket) and `dropped` (frames dropped since the previous answer). A receiving task only
puts frames in a `FrameQueue` (a few waiting frames; when full, the OLDEST waiting frame is
dropped: a live stream wants the latest frame, not a backlog), an answering task takes them out
one at a time. So the memory of a socket is bounded by (queue depth + 1) frames whatever the
client sends. A bad frame is answered with an error message and the stream goes on; when the
socket closes, both tasks stop at once and the waiting frames are thrown away.

`fx=F` gives the camera's focal length in pixels of the frames, `camera=ID` a stored camera
(whole mode; see `Predictor.predict`); without either, the stream learns its camera from the
frames it answers (`service.cameras.stream_camera`; `fx_source: "stream"` once it has).
`smooth=f` (0 <= f < 1, default 0 = off) smooths the probabilities
exponentially over the frames: p_t = f * p_(t-1) + (1 - f) * q_t, with q_t the frame's own
probabilities; class, confidence and region follow p_t, the box and detections stay the
frame's own.

The protocol is documented in docs/live.md.
"""

from __future__ import annotations

import json
import logging
import math
import re
import secrets
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, replace
from enum import IntEnum
from typing import Any, get_args

import anyio
import numpy as np
from prometheus_client import Counter, Gauge
from starlette.websockets import WebSocket, WebSocketDisconnect, WebSocketState

from service import bounded_json
from service.api.schemas import image_result_out
from service.cameras.stream_camera import StreamCamera
from service.core.cells import RegionGrid
from service.core.preprocess import ImageDecodeError, ImageTooLargeError
from service.core.regions import region_of_class
from service.metrics import Metrics
from service.pipeline.focal import KnownFocal
from service.pipeline.job import Options, too_large_code
from service.pipeline.predictor import Prediction, Predictor, Track
from service.pipeline.results import ImageResult, Mode, Region

#: Frames that may wait besides the one being answered; more and the oldest is dropped.
QUEUE_DEPTH = 2
#: Seconds a client without credentials in its handshake has to send `{"api_key": ...}`.
AUTH_TIMEOUT_S = 10.0
MODES: tuple[str, ...] = get_args(Mode)

log = logging.getLogger("uvicorn.error.pose")  # printed by uvicorn's handlers


class CloseCode(IntEnum):
    """WebSocket close codes the stream ends with (4xxx: the HTTP status + 4000)."""

    NORMAL = 1000
    TRY_AGAIN_LATER = 1013  # the model is not loaded (yet): HTTP 503
    UNAUTHORIZED = 4401  # API key missing or wrong: HTTP 401
    INTERNAL_ERROR = 1011  # a bug (logged): HTTP 500
    NOT_FOUND = 4404  # no model or camera of that name: HTTP 404
    CONFLICT = 4409  # the stored camera's row is corrupt (DELETE clears it): HTTP 409
    INVALID_PARAMETERS = 4422  # bad mode / smooth: HTTP 422


class StreamRefused(Exception):
    """The stream cannot start: sent to the client as an error message, then the close code."""

    def __init__(self, close: CloseCode, code: str, message: str) -> None:
        super().__init__(message)
        self.close, self.code, self.message = close, code, message


@dataclass(frozen=True)
class StreamOptions:
    """The query parameters of `/v1/stream`."""

    mode: Mode = "whole"
    smooth: float = 0.0
    model: str | None = None
    fx: float | None = None  # the camera's focal length, px of the frames (`Predictor.predict`)
    camera: str | None = None  # a stored camera's id (`/v1/cameras`)
    grid: RegionGrid | None = None  # the finer regions of `regions=`


def parse_options(query: Mapping[str, str]) -> StreamOptions:
    """`mode`, `smooth`, `model`, `fx`, `camera` and `regions` from the query string, or
    StreamRefused 4422."""
    mode = query.get("mode", "whole")
    if mode not in MODES:
        raise _invalid(f"mode: must be one of {', '.join(MODES)}, got {mode!r}")
    text = query.get("smooth", "0")
    smooth = _number(text)
    if smooth is None:
        raise _invalid(f"smooth: must be a number in [0, 1), got {text!r}")
    if not (math.isfinite(smooth) and 0.0 <= smooth < 1.0):
        raise _invalid(f"smooth: must be in [0, 1) (0 = off), got {text!r}")
    model = query.get("model") or None
    fx = None
    if query.get("fx"):
        fx = _number(query["fx"])
        if fx is None:
            raise _invalid(f"fx: must be a number of pixels, got {query['fx']!r}")
    camera = query.get("camera") or None
    if fx is not None and camera is not None:
        raise _invalid("fx and camera: give one of them")
    grid = None
    if query.get("regions"):
        try:
            grid = RegionGrid.parse(query["regions"])
        except ValueError as exc:
            raise _invalid(str(exc)) from None
    return StreamOptions(mode, smooth, model, fx, camera, grid)  # type: ignore[arg-type]


#: A number in ASCII: decimal, or inf / nan (refused by the ranges after, with their message);
#: Python's float() would also read other scripts' digits (`９００`) and `1_000`.
_NUMBER = re.compile(
    r"[+-]?(?:(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]{1,4})?|inf|infinity|nan)",
    re.ASCII | re.IGNORECASE,
)


def _number(text: str) -> float | None:
    """The number `text` writes in ASCII decimal, or None."""
    return float(text) if _NUMBER.fullmatch(text.strip(" ")) else None


def _invalid(message: str) -> StreamRefused:
    return StreamRefused(CloseCode.INVALID_PARAMETERS, "invalid_parameters", message)


def _unauthorized(message: str) -> StreamRefused:
    return StreamRefused(CloseCode.UNAUTHORIZED, "unauthorized", message)


_KEY_HELP = (
    "send `Authorization: Bearer <key>` or `X-API-Key` in the handshake, `?api_key=<key>` in "
    'the URL, or {"api_key": "<key>"} as the first (text) message'
)


def handshake_key(websocket: WebSocket) -> str | None:
    """The API key the handshake carries: X-API-Key, Authorization Bearer or ?api_key=."""
    given = websocket.headers.get("x-api-key")
    scheme, _, token = websocket.headers.get("authorization", "").partition(" ")
    if given is None and scheme.lower() == "bearer":
        given = token.strip()
    return given if given is not None else websocket.query_params.get("api_key")


async def authorise(websocket: WebSocket, expected: str | None) -> None:
    """Return when the client holds `expected` (None = no key needed), else StreamRefused 4401.

    Without a key in the handshake the first message must be the text `{"api_key": "<key>"}`
    (a browser's WebSocket cannot set headers), within AUTH_TIMEOUT_S seconds.
    """
    if expected is None:
        return
    given = handshake_key(websocket)
    if given is None:
        with anyio.move_on_after(AUTH_TIMEOUT_S):
            given = _key_of(await websocket.receive())
        if given is None:
            raise _unauthorized(f"no API key: {_KEY_HELP}")
    if not secrets.compare_digest(given.encode(), expected.encode()):
        raise _unauthorized(f"wrong API key: {_KEY_HELP}")


def _key_of(message: Mapping[str, Any]) -> str | None:
    if message.get("type") == "websocket.disconnect":
        raise WebSocketDisconnect(int(message.get("code", CloseCode.NORMAL)))
    try:
        body = bounded_json.loads(message.get("text") or "")
    except ValueError:  # not JSON, or nested too deep
        return None
    key = body.get("api_key") if isinstance(body, dict) else None
    return key if isinstance(key, str) else None


async def refuse(websocket: WebSocket, refused: StreamRefused) -> None:
    """Tell the client why in an error message, then close with the refusal's code."""
    if websocket.client_state != WebSocketState.CONNECTED:
        return
    try:
        await websocket.send_text(_error_json(refused.code, refused.message))
        reason = refused.message.encode()[:123].decode(errors="ignore")  # the protocol's limit
        await websocket.close(refused.close, reason)
    except (WebSocketDisconnect, RuntimeError, OSError):
        pass  # the client left first


def _error_json(code: str, message: str, **extra: int) -> str:
    return json.dumps({**extra, "error": {"code": code, "message": message}})


_NOT_A_FRAME = _error_json(
    "bad_request",
    "frames must be binary messages (JPEG or PNG bytes); text is only accepted as the first "
    'message {"api_key": ...}',
)


@dataclass(frozen=True)
class Frame:
    seq: int
    data: bytes


class FrameQueue:
    """The frames waiting to be answered: `put` never waits; beyond `depth` frames the oldest
    is dropped and counted. Single consumer (`get`)."""

    def __init__(self, depth: int = QUEUE_DEPTH) -> None:
        if depth < 1:
            raise ValueError("queue depth must be >= 1")
        self._frames: deque[Frame] = deque()
        self._depth, self._closed = depth, False
        self._ready = anyio.Event()
        self.dropped_since_taken = 0
        self.dropped_total = 0

    def __len__(self) -> int:
        return len(self._frames)

    @property
    def depth(self) -> int:
        return self._depth

    def put(self, frame: Frame) -> int:
        """Queue `frame`; return how many older frames were dropped to make room (0 or 1)."""
        if self._closed:
            return 0
        dropped = 0
        while len(self._frames) >= self._depth:
            self._frames.popleft()
            dropped += 1
        self._frames.append(frame)
        self.dropped_since_taken += dropped
        self.dropped_total += dropped
        self._ready.set()
        return dropped

    async def get(self) -> Frame | None:
        """The oldest waiting frame, waiting for one; None once closed."""
        while not self._frames:
            if self._closed:
                return None
            self._ready = anyio.Event()
            await self._ready.wait()
        return self._frames.popleft()

    def take_dropped(self) -> int:
        """Frames dropped since the last call."""
        count, self.dropped_since_taken = self.dropped_since_taken, 0
        return count

    def close(self) -> None:
        """Throw the waiting frames away and wake the consumer, which then gets None."""
        self._closed = True
        self._frames.clear()
        self._ready.set()


class Smoother:
    """Exponential smoothing of the probabilities: p = f * p_prev + (1 - f) * q (f = 0: off)."""

    def __init__(self, factor: float) -> None:
        if not 0.0 <= factor < 1.0:
            raise ValueError("smoothing factor must be in [0, 1)")
        self.factor = factor
        self._state: np.ndarray | None = None

    def apply(self, result: ImageResult) -> ImageResult:
        """`result` with smoothed probabilities, class, confidence and region (no corners
        when the smoothed class is 0)."""
        if self.factor == 0.0:
            return result
        probs = np.asarray(result.probabilities, dtype=np.float64)
        if self._state is not None:
            probs = self.factor * self._state + (1.0 - self.factor) * probs
        self._state = probs
        class_id = int(probs.argmax())
        return replace(
            result,
            class_id=class_id,
            region=Region(**region_of_class(class_id)),
            probabilities=probs.tolist(),
            confidence=float(probs[class_id]),
            corners=result.corners if class_id != 0 else None,
            pose=result.pose if class_id != 0 else None,
            cell=result.cell if class_id != 0 else None,
        )


class StreamMetrics:
    """Prometheus series of the stream, in the app's registry; frames also count as images."""

    def __init__(self, metrics: Metrics) -> None:
        self.metrics = metrics
        self.sessions = Gauge(
            "pose_stream_sessions",
            "Open /v1/stream sockets.",
            registry=metrics.registry,
            multiprocess_mode="livesum",  # under --workers N: the sum over live workers
        )
        self.frames = Counter(
            "pose_stream_frames",
            "Stream frames by mode and outcome (answered, dropped, error).",
            ["mode", "outcome"],
            registry=metrics.registry,
        )


class StreamSession:
    """One accepted, authorised socket: receive frames, answer them in order until it closes."""

    def __init__(
        self,
        websocket: WebSocket,
        predictor: Predictor,
        options: StreamOptions,
        limiter: anyio.CapacityLimiter,
        metrics: StreamMetrics,
        max_frame_bytes: int,
        focal: KnownFocal | None = None,
        name: str | None = None,
        depth: int = QUEUE_DEPTH,
    ) -> None:
        self.websocket, self.predictor, self.options = websocket, predictor, options
        self.name = name or predictor.model.path.stem  # the served name, the answers' `model`
        self.focal = focal  # the request's (fx= or camera=): else the stream learns one
        size_cm = predictor.model.object_size_cm
        learns = focal is None and options.mode == "whole" and predictor.model.takes_focal
        self.camera = StreamCamera(size_cm) if learns and size_cm is not None else None
        self.limiter, self.metrics, self.max_frame_bytes = limiter, metrics, max_frame_bytes
        self.queue = FrameQueue(depth)
        self.smoother = Smoother(options.smooth)
        self.track: Track | None = None  # where the last frame showed the object
        self.tracked = 0  # frames tracked since the network last answered

    def hello(self) -> dict[str, Any]:
        """The first message: the stream is open and what it runs."""
        return {
            "event": "ready",
            "model": self.name,
            "mode": self.options.mode,
            "smooth": self.options.smooth,
            "fx": self.options.fx,
            "camera": self.options.camera,
            "learns_camera": self.camera is not None,
            "queue": self.queue.depth,
            "max_frame_bytes": self.max_frame_bytes,
        }

    async def run(self) -> None:
        """Serve the socket until the client closes it (or it breaks); never raises for that."""
        self.metrics.sessions.inc()
        try:
            await self.websocket.send_text(json.dumps(self.hello()))
            async with anyio.create_task_group() as tasks:
                tasks.start_soon(self._answer_frames, tasks.cancel_scope)
                await self._receive_frames()
                tasks.cancel_scope.cancel()  # the client left: stop answering now
        except (WebSocketDisconnect, OSError):
            pass
        finally:
            self.queue.close()
            self.metrics.sessions.dec()
            dropped = self.queue.take_dropped()
            if dropped:
                self.metrics.frames.labels(self.options.mode, "dropped").inc(dropped)

    async def _receive_frames(self) -> None:
        """Queue every binary message until the socket closes; answer text with an error."""
        seq = 0
        while True:
            message = await self.websocket.receive()
            if message["type"] == "websocket.disconnect":
                return
            data = message.get("bytes")
            if data is None:
                try:
                    await self._send(_NOT_A_FRAME)
                except (WebSocketDisconnect, RuntimeError, OSError):
                    return
                continue
            self.queue.put(Frame(seq, data))
            seq += 1

    async def _answer_frames(self, scope: anyio.CancelScope) -> None:
        """Answer queued frames one by one, in order; stop when the socket cannot be written."""
        try:
            while (frame := await self.queue.get()) is not None:
                dropped = self.queue.take_dropped()
                if dropped:
                    self.metrics.frames.labels(self.options.mode, "dropped").inc(dropped)
                await self._send(await self._answer(frame, dropped))
        except (WebSocketDisconnect, RuntimeError, OSError):
            scope.cancel()  # the client is gone; the receiver sees it too

    async def _answer(self, frame: Frame, dropped: int) -> str:
        """The JSON message for one frame: its answer, or the error that frame caused."""
        mode, where = self.options.mode, {"seq": frame.seq, "dropped": dropped}
        if len(frame.data) > self.max_frame_bytes:
            self.metrics.frames.labels(mode, "error").inc()
            limit = self.max_frame_bytes
            return _error_json(
                "payload_too_large", f"frame {frame.seq} is larger than {limit} bytes", **where
            )
        try:
            prediction = await anyio.to_thread.run_sync(
                self._predict, frame.data, limiter=self.limiter, abandon_on_cancel=True
            )
        except ImageDecodeError as exc:
            self.metrics.frames.labels(mode, "error").inc()
            code = (
                too_large_code(exc) if isinstance(exc, ImageTooLargeError) else "undecodable_image"
            )
            text = str(exc).removeprefix("image 1: ")
            return _error_json(code, f"frame {frame.seq}: {text}", **where)
        except Exception:  # a bug or a failing session: logged, the stream goes on
            log.exception("stream frame %d (mode %s) failed", frame.seq, mode)
            self.metrics.frames.labels(mode, "error").inc()
            return _error_json(
                "internal_error", f"frame {frame.seq}: internal server error (logged)", **where
            )
        self.metrics.frames.labels(mode, "answered").inc()
        self.metrics.metrics.observe(mode, 1, prediction.inference_s)
        result = self.smoother.apply(prediction.results[0])
        return json.dumps({**where, **image_result_out(result).model_dump(mode="json")})

    def _predict(self, data: bytes) -> Prediction:
        """One frame's answer (with the learned camera once there is one): in whole mode
        tracked from the last frame's corners where it can be, the network looking every
        `Settings.stream_track_every` frames (`Predictor.stream_frame`), else the network's;
        its corners are then offered to the camera the stream learns."""
        known = self.focal or (self.camera.known if self.camera is not None else None)
        # the request's focal length was checked once, when the stream opened; the frame's
        # header is read once, here
        options = Options(self.options.mode, known, grid=self.options.grid)
        job = self.predictor.admit([(None, data)], options)
        last = self.track if self.options.mode == "whole" else None
        prediction, self.tracked = self.predictor.stream_frame(job, last, self.tracked)
        result, pinhole = prediction.results[0], prediction.pinhole[0]
        self.track = None
        if result.corners is not None and result.class_id:
            present = 1.0 - result.probabilities[0]
            self.track = Track(np.array(result.corners), prediction.kappas[0], present)
        if self.camera is not None and pinhole is not None and result.image_size:
            w, h = result.image_size
            self.camera.offer(pinhole, (w, h), prediction.kappas[0], prediction.features[0])
        return prediction

    async def _send(self, text: str) -> None:
        await self.websocket.send_text(text)
