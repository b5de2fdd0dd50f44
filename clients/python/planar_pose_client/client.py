"""`PoseClient` (blocking) and `AsyncPoseClient` (asyncio): the same methods, the same
behaviour; everything but sending and sleeping lives in `_core.ClientCore`.

    with PoseClient("http://127.0.0.1:8000") as client:
        pred = client.predict("photo.jpg")
        print(pred.label, pred.confidence)
"""

from __future__ import annotations

import asyncio
import time
from abc import ABC, abstractmethod
from collections.abc import AsyncIterable, AsyncIterator, Iterable, Iterator
from typing import Any, Generic, TypeVar

import httpx

from ._core import DEFAULT_TIMEOUT_S, ClientCore, RetryPolicy
from .errors import PoseError
from .images import ImageInput
from .models import Mode, ModelCard, ModelList, Prediction
from .stream import DEFAULT_WINDOW, StreamItem, StreamMode, astream_frames, stream_frames

H = TypeVar("H", httpx.Client, httpx.AsyncClient)
T = TypeVar("T", httpx.BaseTransport, httpx.AsyncBaseTransport)


class _ClientBase(ABC, Generic[H, T]):
    """Construction shared by both clients; `_connect` opens their kind of httpx client."""

    def __init__(
        self,
        base_url: str = "http://127.0.0.1:8000",
        api_key: str | None = None,
        *,
        timeout: float | httpx.Timeout = DEFAULT_TIMEOUT_S,
        retries: int = 2,
        backoff: float = 0.25,
        backoff_max: float = 5.0,
        transport: T | None = None,
    ) -> None:
        """
        base_url: where the service listens, e.g. "http://127.0.0.1:8000".
        api_key: sent as `Authorization: Bearer <key>` when the service requires one.
        timeout: seconds per HTTP request (or an httpx.Timeout).
        retries: extra attempts after a connection failure or a 502/503/504 answer (never on
            other errors); backoff, backoff_max: first wait and cap in seconds, doubled per
            retry, with jitter (see RetryPolicy).
        transport: an httpx transport to send through instead of the network, e.g.
            `httpx.MockTransport(handler)` in tests or `httpx.ASGITransport(app)` (async).
        Raises ValueError for a base_url that is not http(s)://host[:port].
        """
        retry = RetryPolicy(retries, backoff, backoff_max)
        self._core = ClientCore(base_url, api_key, timeout, retry)
        options = self._core.http_options()
        if transport is not None:
            options["transport"] = transport
        self._http: H = self._connect(options)

    @abstractmethod
    def _connect(self, options: dict[str, Any]) -> H:
        """An httpx client (sync or async) built with `options`."""

    @property
    def base_url(self) -> str:
        return self._core.base_url


class PoseClient(_ClientBase[httpx.Client, httpx.BaseTransport]):
    """Blocking client of the planar-pose service. Use it as a context manager (or call
    `close`) to release its connections."""

    def _connect(self, options: dict[str, Any]) -> httpx.Client:
        return httpx.Client(**options)

    def predict(
        self,
        image: ImageInput,
        mode: Mode = "whole",
        model: str | None = None,
        fx: float | None = None,
    ) -> Prediction:
        """Pose region of one image (path, bytes, binary file object or numpy array), by the
        default model or the served model `model` (see `models()`); `fx`: the camera's focal
        length in pixels of the image, if known (whole mode)."""
        return self.predict_many([image], mode, model, fx)[0]

    def predict_many(
        self,
        images: Iterable[ImageInput],
        mode: Mode = "whole",
        model: str | None = None,
        fx: float | None = None,
    ) -> list[Prediction]:
        """Pose regions of several images in one request; results in the order given (`fx`:
        the camera's focal length in pixels of the images, as in `predict`)."""
        request = self._core.predict_request(images, mode, model, fx)
        return self._core.parse_predictions(self._send(**request), len(request["files"]))

    def model_info(self) -> ModelCard:
        """The default model's card (GET /v1/model)."""
        return self._core.parse_model_card(self._send("GET", "/v1/model"))

    def models(self) -> ModelList:
        """Every served model (GET /v1/models)."""
        return self._core.parse_model_list(self._send("GET", "/v1/models"))

    def stream(
        self,
        frames: Iterable[ImageInput],
        mode: StreamMode = "whole",
        smooth: float = 0.0,
        model: str | None = None,
        window: int | None = DEFAULT_WINDOW,
    ) -> Iterator[StreamItem]:
        """Send `frames` through WS /v1/stream; yield one answer per frame, in order
        (`StreamPrediction`, or `FrameError` for a frame the service refused). See
        `planar_pose_client.stream` for `smooth` and `window`."""
        return stream_frames(self._core, frames, mode, smooth, model, window)

    def health(self) -> bool:
        """Liveness (GET /healthz, one attempt): False when unreachable or answering an error."""
        return self._probe("/healthz")

    def ready(self) -> bool:
        """Readiness (GET /readyz, one attempt): True once the model is loaded."""
        return self._probe("/readyz")

    def close(self) -> None:
        self._http.close()

    def __enter__(self) -> PoseClient:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def _probe(self, path: str) -> bool:
        try:
            self._send("GET", path, retries=0)
        except PoseError:
            return False
        return True

    def _send(self, method: str, url: str, retries: int | None = None, **kw: Any) -> httpx.Response:
        retry = 0
        while True:
            response, error = None, None
            try:
                response = self._http.request(method, url, **kw)
            except httpx.TransportError as exc:
                error = exc
            outcome = self._core.after_attempt(retry, response, error, retries)
            if isinstance(outcome, httpx.Response):
                return outcome
            time.sleep(outcome)
            retry += 1


class AsyncPoseClient(_ClientBase[httpx.AsyncClient, httpx.AsyncBaseTransport]):
    """Asyncio client of the planar-pose service: the methods of PoseClient as coroutines.
    Use it with `async with` (or await `aclose`) to release its connections."""

    def _connect(self, options: dict[str, Any]) -> httpx.AsyncClient:
        return httpx.AsyncClient(**options)

    async def predict(
        self,
        image: ImageInput,
        mode: Mode = "whole",
        model: str | None = None,
        fx: float | None = None,
    ) -> Prediction:
        """Pose region of one image (path, bytes, binary file object or numpy array), by the
        default model or the served model `model` (see `models()`); `fx`: the camera's focal
        length in pixels of the image, if known (whole mode)."""
        return (await self.predict_many([image], mode, model, fx))[0]

    async def predict_many(
        self,
        images: Iterable[ImageInput],
        mode: Mode = "whole",
        model: str | None = None,
        fx: float | None = None,
    ) -> list[Prediction]:
        """Pose regions of several images in one request; results in the order given (`fx`:
        the camera's focal length in pixels of the images, as in `predict`)."""
        request = self._core.predict_request(images, mode, model, fx)
        return self._core.parse_predictions(await self._send(**request), len(request["files"]))

    async def model_info(self) -> ModelCard:
        """The default model's card (GET /v1/model)."""
        return self._core.parse_model_card(await self._send("GET", "/v1/model"))

    async def models(self) -> ModelList:
        """Every served model (GET /v1/models)."""
        return self._core.parse_model_list(await self._send("GET", "/v1/models"))

    def stream(
        self,
        frames: Iterable[ImageInput] | AsyncIterable[ImageInput],
        mode: StreamMode = "whole",
        smooth: float = 0.0,
        model: str | None = None,
        window: int | None = DEFAULT_WINDOW,
    ) -> AsyncIterator[StreamItem]:
        """`async for answer in client.stream(frames)`: PoseClient.stream for asyncio;
        `frames` may be an async iterable."""
        return astream_frames(self._core, frames, mode, smooth, model, window)

    async def health(self) -> bool:
        """Liveness (GET /healthz, one attempt): False when unreachable or answering an error."""
        return await self._probe("/healthz")

    async def ready(self) -> bool:
        """Readiness (GET /readyz, one attempt): True once the model is loaded."""
        return await self._probe("/readyz")

    async def aclose(self) -> None:
        await self._http.aclose()

    async def __aenter__(self) -> AsyncPoseClient:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()

    async def _probe(self, path: str) -> bool:
        try:
            await self._send("GET", path, retries=0)
        except PoseError:
            return False
        return True

    async def _send(
        self, method: str, url: str, retries: int | None = None, **kw: Any
    ) -> httpx.Response:
        retry = 0
        while True:
            response, error = None, None
            try:
                response = await self._http.request(method, url, **kw)
            except httpx.TransportError as exc:
                error = exc
            outcome = self._core.after_attempt(retry, response, error, retries)
            if isinstance(outcome, httpx.Response):
                return outcome
            await asyncio.sleep(outcome)
            retry += 1
