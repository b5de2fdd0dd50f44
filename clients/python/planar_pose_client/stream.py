"""Live stream of frames through `WS /v1/stream` (the `websockets` library): each frame goes
out as one binary message, each answer comes back in order with the frame's `seq`.

    with PoseClient("http://127.0.0.1:8000") as client:
        for answer in client.stream(frames, mode="whole"):   # paths, bytes or RGB arrays
            if answer.ok:
                print(answer.seq, answer.label, answer.confidence)
            else:
                print(answer.seq, "error:", answer.message)   # a bad frame; the stream goes on

`window` frames at most are sent without their answer (default 2: every frame is answered as
fast as the service can); `window=None` sends as fast as the frames come and lets the service
drop the oldest waiting frames (`answer.dropped` counts them), which is what a live camera
wants. The connection opens when the iteration starts and closes when it ends (or breaks).
No retries: a stream that cannot open or breaks raises a `PoseError`.
"""

from __future__ import annotations

import asyncio
import json
import threading
from collections.abc import AsyncIterable, AsyncIterator, Iterable, Iterator
from typing import Any, Literal
from urllib.parse import urlencode

from pydantic import Field, ValidationError
from websockets.asyncio.client import ClientConnection as AsyncConnection
from websockets.asyncio.client import connect as async_connect
from websockets.exceptions import ConnectionClosed, InvalidStatus, InvalidURI, WebSocketException
from websockets.sync.client import ClientConnection, connect

from ._core import ClientCore, check_camera_id, check_positive
from .errors import (
    AuthError,
    CameraCorruptError,
    CameraNotFoundError,
    InvalidRequestError,
    ModelNotFoundError,
    PoseConnectionError,
    PoseError,
    ServiceUnavailable,
)
from .images import ImageInput, is_numpy_array, to_upload
from .models import Prediction, _Answer

StreamMode = Literal["whole", "sliding", "proposals"]
DEFAULT_WINDOW = 2
_POLL_S = 0.05  # how often a waiting receiver checks whether the sender has finished
JPEG_QUALITY = 90  # numpy frames are sent as JPEG when OpenCV is installed, else PNG

#: Close codes of the service -> (exception class, HTTP status it stands for).
_CLOSE_ERRORS: dict[int, tuple[type[PoseError], int]] = {
    4401: (AuthError, 401),
    4404: (PoseError, 404),
    4409: (CameraCorruptError, 409),
    4422: (InvalidRequestError, 422),
    1013: (ServiceUnavailable, 503),
}


class StreamPrediction(Prediction):
    """The answer for one frame: a `Prediction` plus its sequence number."""

    seq: int = Field(ge=0, description="0-based index of the frame on this stream")
    dropped: int = Field(0, ge=0, description="frames the service dropped before this one")

    @property
    def ok(self) -> bool:
        return True


class FrameError(_Answer):
    """A frame the service could not answer (e.g. not an image); the stream goes on."""

    seq: int = Field(ge=0)
    dropped: int = Field(0, ge=0)
    code: str
    message: str

    @property
    def ok(self) -> bool:
        return False


StreamItem = StreamPrediction | FrameError


def stream_url(
    base_url: str,
    mode: str,
    smooth: float,
    model: str | None,
    fx: float | None = None,
    camera: str | None = None,
) -> str:
    """ws(s)://host/v1/stream?... for an http(s) base URL. ValueError for an fx that is not
    a positive number, a malformed camera id, or both given."""
    scheme, rest = base_url.split("://", 1)
    query: dict[str, Any] = {"mode": mode}
    if smooth:
        query["smooth"] = smooth
    if model:
        query["model"] = model
    if fx is not None:
        query["fx"] = check_positive(fx, "fx")
    if camera is not None:
        if fx is not None:
            raise ValueError("give fx or camera, not both (the camera has its own fx)")
        query["camera"] = check_camera_id(camera)
    return f"{'wss' if scheme == 'https' else 'ws'}://{rest}/v1/stream?{urlencode(query)}"


def frame_bytes(image: ImageInput, index: int) -> bytes:
    """Encoded bytes of one frame: files and bytes as they are, RGB arrays as JPEG (PNG
    without OpenCV). Raises like `to_upload` for a bad input."""
    if is_numpy_array(image):
        try:
            import cv2
        except ImportError:
            return to_upload(image, index).data
        if image.ndim == 3 and image.shape[-1] == 3 and image.dtype.name == "uint8":
            bgr = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
            ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
            if ok:
                return bytes(buf.tobytes())
    return to_upload(image, index).data


def parse_message(text: str | bytes) -> StreamItem | None:
    """A message of the service: an answer, a frame error, None for the `ready` hello or a
    note that is about no frame. Raises PoseError for a refusal or a malformed answer."""
    try:
        body = json.loads(text)
        if not isinstance(body, dict):
            raise ValueError("not a JSON object")
        if body.get("event") == "ready":
            return None
        error = body.get("error")
        if isinstance(error, dict):
            if "seq" not in body:
                return None  # e.g. a text message we never send; nothing to answer
            return FrameError(
                seq=body["seq"],
                dropped=body.get("dropped", 0),
                code=str(error.get("code", "error")),
                message=str(error.get("message", "")),
            )
        return StreamPrediction.model_validate(body)
    except (ValueError, ValidationError) as exc:
        raise PoseError(
            f"unexpected message on the stream: {exc}", code="invalid_response"
        ) from exc


def _refusal(text: str | bytes) -> tuple[str, str] | None:
    """(code, message) of a refusal message (an error about no frame), else None."""
    try:
        body = json.loads(text)
    except ValueError:
        return None
    error = body.get("error") if isinstance(body, dict) else None
    if isinstance(error, dict) and "seq" not in body:
        return str(error.get("code", "error")), str(error.get("message", ""))
    return None


def closed_error(exc: ConnectionClosed, refusal: tuple[str, str] | None, url: str) -> PoseError:
    """The PoseError for a stream the service closed (refused, or broken mid-stream)."""
    close = exc.rcvd.code if exc.rcvd is not None else 1006
    reason = exc.rcvd.reason if exc.rcvd is not None else ""
    if close in _CLOSE_ERRORS:
        cls, status = _CLOSE_ERRORS[close]
        code, message = refusal or ("error", reason or f"closed with code {close}")
        if close == 4404:  # what is missing: a camera (camera=ID) or a model (model=NAME)
            cls = CameraNotFoundError if "camera" in code else ModelNotFoundError
        return cls(message, status=status, code=code)
    return PoseConnectionError(
        f"the stream {url} closed unexpectedly (code {close}{': ' + reason if reason else ''})",
        attempts=1,
        code="stream_closed",
    )


def open_error(exc: BaseException, url: str) -> PoseError:
    """The PoseError for a stream that could not open."""
    if isinstance(exc, InvalidStatus):
        status = exc.response.status_code
        cls = {401: AuthError, 503: ServiceUnavailable}.get(status, PoseError)
        hint = " (does this service have /v1/stream?)" if status in (403, 404) else ""
        return cls(
            f"the service refused the stream {url}: HTTP {status}{hint}",
            status=status,
            code=f"http_{status}",
        )
    if isinstance(exc, InvalidURI):
        return PoseError(f"bad stream URL {url}: {exc}", code="bad_url")
    what = "timed out" if isinstance(exc, TimeoutError) else f"{type(exc).__name__}: {exc}"
    return PoseConnectionError(f"cannot open the stream {url}: {what}", attempts=1)


class _Tally:
    """Frames sent vs accounted for (answered, refused or dropped), shared by both directions."""

    def __init__(self) -> None:
        self.sent = 0
        self.accounted = 0
        self.done = False  # no more frames will be sent
        self.failure: BaseException | None = None  # raised by the frames or their encoding

    def finished(self) -> bool:
        return self.done and self.accounted >= self.sent


def _connect_options(core: ClientCore) -> dict[str, Any]:
    """Keyword arguments of websockets' `connect`, the same for the sync and async clients:
    the API key header, no compression (JPEG/PNG frames), the client's connect timeout."""
    return {
        "additional_headers": {k: v for k, v in core.headers.items() if k == "Authorization"},
        "compression": None,
        "open_timeout": core.timeout.connect,
        "user_agent_header": "planar-pose-client",
    }


def stream_frames(
    core: ClientCore,
    frames: Iterable[ImageInput],
    mode: StreamMode = "whole",
    smooth: float = 0.0,
    model: str | None = None,
    window: int | None = DEFAULT_WINDOW,
    fx: float | None = None,
    camera: str | None = None,
) -> Iterator[StreamItem]:
    """Blocking: send `frames` from a thread, yield the answers in order (see the module)."""
    _check_window(window)
    url = stream_url(core.base_url, mode, smooth, model, fx, camera)
    try:
        ws = connect(url, **_connect_options(core))
    except (OSError, TimeoutError, WebSocketException) as exc:
        raise open_error(exc, url) from exc
    tally, credit = _Tally(), threading.Semaphore(window) if window else None
    stop = threading.Event()
    with ws:
        _wait_ready(lambda: ws.recv(timeout=core.timeout.connect), url)
        sender = threading.Thread(
            target=_send_all, args=(ws, frames, tally, credit, stop), daemon=True
        )
        sender.start()
        try:
            yield from _receive_all(ws, tally, credit, url)
        finally:
            stop.set()
            if credit is not None:
                credit.release(window or 1)  # wake a sender waiting for credit
    sender.join(timeout=5)


def _check_window(window: int | None) -> None:
    if window is not None and window < 1:
        raise ValueError("window must be >= 1 (frames without an answer) or None (no limit)")


def _wait_ready(recv: Any, url: str) -> None:
    """Read the hello; a refusal (auth, parameters, not ready) raises its PoseError."""
    refusal = None
    try:
        refusal = _refusal(recv())
        if refusal is None:
            return
        recv()  # the close frame that follows the refusal
    except ConnectionClosed as exc:
        raise closed_error(exc, refusal, url) from None
    except TimeoutError:
        raise PoseConnectionError(f"the stream {url} did not say ready", attempts=1) from None
    raise PoseError(refusal[1], code=refusal[0])


def _send_all(
    ws: ClientConnection,
    frames: Iterable[ImageInput],
    tally: _Tally,
    credit: threading.Semaphore | None,
    stop: threading.Event,
) -> None:
    try:
        for i, frame in enumerate(frames):
            data = frame_bytes(frame, i)
            if credit is not None:
                credit.acquire()
            if stop.is_set():
                return
            ws.send(data)
            tally.sent += 1
    except ConnectionClosed:
        pass  # the receiver reports why
    except BaseException as exc:  # a bad frame object or a failing frame source
        tally.failure = exc
    finally:
        tally.done = True


def _receive_all(
    ws: ClientConnection, tally: _Tally, credit: threading.Semaphore | None, url: str
) -> Iterator[StreamItem]:
    while not tally.finished():
        if tally.failure is not None:
            raise tally.failure
        try:
            text = ws.recv(timeout=_POLL_S)
        except TimeoutError:
            continue
        except ConnectionClosed as exc:
            raise closed_error(exc, None, url) from None
        item = parse_message(text)
        if item is None:
            continue
        tally.accounted += 1 + item.dropped
        if credit is not None:
            credit.release(1 + item.dropped)
        yield item
    if tally.failure is not None:
        raise tally.failure


async def astream_frames(
    core: ClientCore,
    frames: Iterable[ImageInput] | AsyncIterable[ImageInput],
    mode: StreamMode = "whole",
    smooth: float = 0.0,
    model: str | None = None,
    window: int | None = DEFAULT_WINDOW,
    fx: float | None = None,
    camera: str | None = None,
) -> AsyncIterator[StreamItem]:
    """Asyncio: send `frames` (an iterable or async iterable) from a task, yield the answers."""
    _check_window(window)
    url = stream_url(core.base_url, mode, smooth, model, fx, camera)
    try:
        ws = await async_connect(url, **_connect_options(core))
    except (OSError, TimeoutError, WebSocketException) as exc:
        raise open_error(exc, url) from exc
    tally, credit = _Tally(), asyncio.Semaphore(window) if window else None
    async with ws:
        await _await_ready(ws, url, core.timeout.connect)
        sender = asyncio.create_task(_asend_all(ws, frames, tally, credit))
        try:
            async for item in _areceive_all(ws, tally, credit, url):
                yield item
        finally:
            sender.cancel()
            await asyncio.gather(sender, return_exceptions=True)


async def _await_ready(ws: AsyncConnection, url: str, timeout: float | None) -> None:
    refusal = None
    try:
        refusal = _refusal(await asyncio.wait_for(ws.recv(), timeout))
        if refusal is None:
            return
        await ws.recv()
    except ConnectionClosed as exc:
        raise closed_error(exc, refusal, url) from None
    except TimeoutError:
        raise PoseConnectionError(f"the stream {url} did not say ready", attempts=1) from None
    raise PoseError(refusal[1], code=refusal[0])


async def _asend_all(
    ws: AsyncConnection,
    frames: Iterable[ImageInput] | AsyncIterable[ImageInput],
    tally: _Tally,
    credit: asyncio.Semaphore | None,
) -> None:
    async def send(frame: ImageInput) -> None:
        data = frame_bytes(frame, tally.sent)
        if credit is not None:
            await credit.acquire()
        await ws.send(data)
        tally.sent += 1

    try:
        if isinstance(frames, AsyncIterable):
            async for frame in frames:
                await send(frame)
        else:
            for frame in frames:
                await send(frame)
    except ConnectionClosed:
        pass
    except Exception as exc:
        tally.failure = exc
    finally:
        tally.done = True


async def _areceive_all(
    ws: AsyncConnection, tally: _Tally, credit: asyncio.Semaphore | None, url: str
) -> AsyncIterator[StreamItem]:
    while not tally.finished():
        if tally.failure is not None:
            raise tally.failure
        try:
            text = await asyncio.wait_for(ws.recv(), _POLL_S)
        except TimeoutError:
            continue
        except ConnectionClosed as exc:
            raise closed_error(exc, None, url) from None
        item = parse_message(text)
        if item is None:
            continue
        tally.accounted += 1 + item.dropped
        if credit is not None:
            for _ in range(1 + item.dropped):
                credit.release()
        yield item
    if tally.failure is not None:
        raise tally.failure


__all__ = [
    "DEFAULT_WINDOW",
    "FrameError",
    "StreamItem",
    "StreamMode",
    "StreamPrediction",
    "astream_frames",
    "stream_frames",
]
