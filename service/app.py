"""The HTTP service: FastAPI over one shared onnxruntime session.

`uvicorn service.app:app` serves with settings from the environment (`POSE_*`); `create_app`
builds an app from explicit settings (the `planar-pose serve` command, tests).
"""

from __future__ import annotations

import asyncio
import logging
import secrets
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Annotated, Any

import anyio
import cv2
from fastapi import Depends, FastAPI, Query, Request
from fastapi.middleware.cors import CORSMiddleware
from fastapi.responses import Response
from pydantic import ValidationError

from service.errors import ApiError, install_error_handlers
from service.limits import BodyLimitMiddleware
from service.metrics import Metrics, MetricsMiddleware
from service.model import ModelLoadError, PoseModel
from service.predictor import Predictor
from service.preprocess import ImageDecodeError, ImageTooLargeError
from service.schemas import ErrorResponse, Mode, PredictResponse, Status
from service.settings import Settings
from service.uploads import read_images

log = logging.getLogger("uvicorn.error.pose")  # printed by uvicorn's handlers

_ERRORS: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorResponse, "description": text}
    for code, text in {
        400: "Undecodable or empty image, malformed body.",
        401: "API key missing or wrong (when POSE_API_KEY is set).",
        413: "Body too large, too many images, or too many pixels in an image.",
        415: "Unsupported content type.",
        422: "Bad parameters (e.g. mode).",
        503: "Model not loaded (yet).",
    }.items()
}

_PREDICT_BODY = {
    "requestBody": {
        "required": True,
        "content": {
            "multipart/form-data": {
                "schema": {
                    "type": "object",
                    "properties": {
                        "image": {
                            "type": "array",
                            "items": {"type": "string", "format": "binary"},
                            "description": "One or many images (JPEG, PNG, WebP, BMP, GIF).",
                        }
                    },
                    "required": ["image"],
                }
            },
            "image/*": {"schema": {"type": "string", "format": "binary"}},
        },
    }
}


class _State:
    """What the endpoints share: the predictor once the model is loaded, or why it is not."""

    def __init__(self) -> None:
        self.predictor: Predictor | None = None
        self.problem = "model is loading"


def create_app(settings: Settings | None = None) -> FastAPI:
    """The FastAPI app; the model loads in the background after startup (see /readyz)."""
    settings = settings or Settings()
    state, metrics = _State(), Metrics()
    # OpenCV would log every refused upload to stderr; the client's 400 already says it.
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_FATAL)
    # CPU-bound jobs beyond one per core only thrash caches and lengthen the tail: queue them.
    jobs = anyio.CapacityLimiter(settings.workers)

    def load() -> None:
        path = settings.resolved_model_path
        try:
            model = PoseModel.load(path, settings.intra_op_threads, settings.inter_op_threads)
        except ModelLoadError as exc:
            state.problem = f"model not loaded: {exc}"
            log.error("%s", state.problem)
            return
        state.predictor = Predictor(model, settings)
        log.info("model %s loaded from %s, input %s", model.name, path, model.input_size)

    @asynccontextmanager
    async def lifespan(_: FastAPI) -> AsyncIterator[None]:
        task = asyncio.create_task(asyncio.to_thread(load))
        yield
        await task

    app = FastAPI(
        title="planar-pose",
        summary="Coarse camera pose region of a known planar object from one photograph.",
        version="1",
        lifespan=lifespan,
    )
    install_error_handlers(app)

    def predictor() -> Predictor:
        if state.predictor is None:
            raise ApiError(503, "not_ready", state.problem)
        return state.predictor

    async def authorise(request: Request) -> None:
        if settings.api_key is None:
            return
        given = request.headers.get("x-api-key")
        scheme, _, token = request.headers.get("authorization", "").partition(" ")
        if given is None and scheme.lower() == "bearer":
            given = token.strip()
        expected = settings.api_key.get_secret_value().encode()
        if given is None or not secrets.compare_digest(given.encode(), expected):
            raise ApiError(
                401,
                "unauthorized",
                "missing or wrong API key: send `Authorization: Bearer <key>` or `X-API-Key`",
                {"WWW-Authenticate": "Bearer"},
            )

    @app.post(
        "/v1/predict",
        response_model=PredictResponse,
        responses=_ERRORS,
        dependencies=[Depends(authorise)],
        openapi_extra=_PREDICT_BODY,
        summary="Pose class of one or many images",
    )
    async def predict(
        request: Request,
        mode: Annotated[
            Mode,
            Query(
                description="whole: the image as is; sliding: best window of a grid; "
                "proposals: best object proposal (SPEC 9)."
            ),
        ] = "whole",
    ) -> PredictResponse:
        """Send images as multipart field `image` (repeat it for many) or one raw image body.

        All images of a request go through one batched network call.
        """
        runner = predictor()
        images = await read_images(request, settings.max_images)
        try:
            prediction = await anyio.to_thread.run_sync(runner.predict, images, mode, limiter=jobs)
        except ImageTooLargeError as exc:
            raise ApiError(413, "image_too_large", str(exc)) from None
        except ImageDecodeError as exc:
            raise ApiError(400, "undecodable_image", str(exc)) from None
        metrics.images.labels(mode).inc(len(images))
        metrics.inference.labels(mode).observe(prediction.inference_s)
        return PredictResponse(model=runner.model.name, mode=mode, results=prediction.results)

    @app.get("/v1/model", responses=_ERRORS, dependencies=[Depends(authorise)])
    async def model_card() -> dict[str, Any]:
        """The model card: name, version, input size, classes, profile, training, accuracy."""
        return predictor().model.card

    @app.get("/healthz", response_model=Status, response_model_exclude_none=True)
    async def healthz() -> Status:
        """The process is up (liveness)."""
        return Status(status="ok")

    @app.get("/readyz", response_model=Status, responses={503: _ERRORS[503]})
    async def readyz() -> Status:
        """The model is loaded and requests can be answered (readiness)."""
        return Status(status="ready", model=predictor().model.name)

    @app.get("/metrics", response_class=Response)
    async def prometheus() -> Response:
        """Prometheus text format."""
        return Response(metrics.render(), media_type=Metrics.content_type)

    routes = frozenset(getattr(r, "path", "") for r in app.routes)
    app.add_middleware(BodyLimitMiddleware, max_bytes=settings.max_upload_bytes)
    if settings.cors_origins:
        app.add_middleware(
            CORSMiddleware,
            allow_origins=settings.cors_origins,
            allow_methods=["GET", "POST"],
            allow_headers=["Authorization", "X-API-Key", "Content-Type"],
        )
    app.add_middleware(MetricsMiddleware, metrics=metrics, routes=routes)
    return app


try:
    app = create_app()
except ValidationError as _exc:  # `uvicorn service.app:app` with bad POSE_* variables
    raise SystemExit(f"error: invalid settings (POSE_* environment):\n{_exc}") from None
