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
from collections.abc import AsyncIterable, AsyncIterator, Iterable, Iterator, Sequence
from typing import Any, Generic, TypeVar

import httpx

from ._core import DEFAULT_TIMEOUT_S, ClientCore, RetryPolicy
from .errors import PoseError
from .images import ImageInput
from .models import Camera, Mode, ModelCard, ModelList, Prediction
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
        *,
        camera: str | None = None,
        regions: str | None = None,
        same_camera: bool = False,
    ) -> Prediction:
        """Pose region of one image (path, bytes, binary file object or numpy array), by the
        default model or the served model `model` (see `models()`). Whole mode, corner
        models: `Prediction.pose` is the camera's pose, with `fx` (the camera's focal length
        in pixels of the image) or the stored `camera` id (see `cameras()`) if known, else fx
        estimated; `regions` ("8x3" or "8x3x60,120") adds the finer `Prediction.cell`."""
        return self.predict_many(
            [image], mode, model, fx, camera=camera, regions=regions, same_camera=same_camera
        )[0]

    def predict_many(
        self,
        images: Iterable[ImageInput],
        mode: Mode = "whole",
        model: str | None = None,
        fx: float | None = None,
        *,
        camera: str | None = None,
        regions: str | None = None,
        same_camera: bool = False,
    ) -> list[Prediction]:
        """Pose regions of several images in one request; results in the order given (`fx`,
        `camera`, `regions` as in `predict`). `same_camera=True`: the images come from one
        camera, whose fx the service estimates jointly from all of them."""
        request = self._core.predict_request(images, mode, model, fx, camera, regions, same_camera)
        return self._core.parse_predictions(self._send(**request), len(request["files"]))

    def create_camera(
        self,
        fx: float,
        *,
        fy: float | None = None,
        cx: float | None = None,
        cy: float | None = None,
        dist: Sequence[float] | None = None,
        width: int | None = None,
        height: int | None = None,
        name: str | None = None,
    ) -> Camera:
        """Store a camera given by its intrinsics (POST /v1/cameras): focal length `fx` in
        pixels at image width `width` (without `width` fx is used as is for every image),
        optionally `fy`, the principal point `cx`, `cy`, OpenCV's distortion `dist` [k1, k2,
        p1, p2, k3] and a `name`. Pass the answer's `id` as `camera=`."""
        request = self._core.create_camera_request(fx, fy, cx, cy, dist, width, height, name)
        return self._core.parse_camera(self._send(**request, idempotent=False))

    def learn_camera(
        self,
        photos: Iterable[ImageInput],
        model: str | None = None,
        name: str | None = None,
    ) -> Camera:
        """Let the service learn a camera from `photos` of the object it took (3 or more,
        all of one size, from different angles; POST /v1/cameras, multipart), found by the
        corner model `model` (default: the default model). InvalidRequestError (422) when
        too few show the object or the views do not pin the focal length."""
        request = self._core.learn_camera_request(photos, model, name)
        return self._core.parse_camera(self._send(**request, idempotent=False))

    def cameras(self) -> list[Camera]:
        """Every stored camera, newest first (GET /v1/cameras)."""
        return self._core.parse_camera_list(self._send("GET", "/v1/cameras"))

    def camera(self, camera_id: str) -> Camera:
        """One stored camera (GET /v1/cameras/{id}); CameraNotFoundError for an unknown id."""
        return self._core.parse_camera(self._send("GET", self._core.camera_url(camera_id)))

    def delete_camera(self, camera_id: str) -> None:
        """Forget a stored camera (DELETE /v1/cameras/{id}); CameraNotFoundError for an
        unknown id."""
        self._send("DELETE", self._core.camera_url(camera_id), idempotent=False)

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
        *,
        fx: float | None = None,
        camera: str | None = None,
    ) -> Iterator[StreamItem]:
        """Send `frames` through WS /v1/stream; yield one answer per frame, in order
        (`StreamPrediction`, or `FrameError` for a frame the service refused). See
        `planar_pose_client.stream` for `smooth` and `window`. `fx` (px of the frames) or a
        stored `camera` id: the camera's focal length for the pose; without either the
        stream learns it from the frames (`pose.fx_source == "stream"`)."""
        return stream_frames(self._core, frames, mode, smooth, model, window, fx, camera)

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

    def _send(
        self,
        method: str,
        url: str,
        retries: int | None = None,
        idempotent: bool = True,
        **kw: Any,
    ) -> httpx.Response:
        retry = 0
        while True:
            response, error = None, None
            try:
                response = self._http.request(method, url, **kw)
            except httpx.TransportError as exc:
                error = exc
            outcome = self._core.after_attempt(retry, response, error, retries, idempotent)
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
        *,
        camera: str | None = None,
        regions: str | None = None,
        same_camera: bool = False,
    ) -> Prediction:
        """Pose region of one image: PoseClient.predict (`pose`, `camera`, `regions` alike)."""
        return (
            await self.predict_many(
                [image], mode, model, fx, camera=camera, regions=regions, same_camera=same_camera
            )
        )[0]

    async def predict_many(
        self,
        images: Iterable[ImageInput],
        mode: Mode = "whole",
        model: str | None = None,
        fx: float | None = None,
        *,
        camera: str | None = None,
        regions: str | None = None,
        same_camera: bool = False,
    ) -> list[Prediction]:
        """Pose regions of several images in one request: PoseClient.predict_many."""
        request = self._core.predict_request(images, mode, model, fx, camera, regions, same_camera)
        return self._core.parse_predictions(await self._send(**request), len(request["files"]))

    async def create_camera(
        self,
        fx: float,
        *,
        fy: float | None = None,
        cx: float | None = None,
        cy: float | None = None,
        dist: Sequence[float] | None = None,
        width: int | None = None,
        height: int | None = None,
        name: str | None = None,
    ) -> Camera:
        """Store a camera given by its intrinsics: PoseClient.create_camera."""
        request = self._core.create_camera_request(fx, fy, cx, cy, dist, width, height, name)
        return self._core.parse_camera(await self._send(**request, idempotent=False))

    async def learn_camera(
        self,
        photos: Iterable[ImageInput],
        model: str | None = None,
        name: str | None = None,
    ) -> Camera:
        """Learn a camera from photos of the object: PoseClient.learn_camera."""
        request = self._core.learn_camera_request(photos, model, name)
        return self._core.parse_camera(await self._send(**request, idempotent=False))

    async def cameras(self) -> list[Camera]:
        """Every stored camera, newest first (GET /v1/cameras)."""
        return self._core.parse_camera_list(await self._send("GET", "/v1/cameras"))

    async def camera(self, camera_id: str) -> Camera:
        """One stored camera (GET /v1/cameras/{id}); CameraNotFoundError for an unknown id."""
        return self._core.parse_camera(await self._send("GET", self._core.camera_url(camera_id)))

    async def delete_camera(self, camera_id: str) -> None:
        """Forget a stored camera (DELETE /v1/cameras/{id}); CameraNotFoundError if unknown."""
        await self._send("DELETE", self._core.camera_url(camera_id), idempotent=False)

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
        *,
        fx: float | None = None,
        camera: str | None = None,
    ) -> AsyncIterator[StreamItem]:
        """`async for answer in client.stream(frames)`: PoseClient.stream for asyncio;
        `frames` may be an async iterable."""
        return astream_frames(self._core, frames, mode, smooth, model, window, fx, camera)

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
        self,
        method: str,
        url: str,
        retries: int | None = None,
        idempotent: bool = True,
        **kw: Any,
    ) -> httpx.Response:
        retry = 0
        while True:
            response, error = None, None
            try:
                response = await self._http.request(method, url, **kw)
            except httpx.TransportError as exc:
                error = exc
            outcome = self._core.after_attempt(retry, response, error, retries, idempotent)
            if isinstance(outcome, httpx.Response):
                return outcome
            await asyncio.sleep(outcome)
            retry += 1
