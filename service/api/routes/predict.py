"""POST /v1/predict: images in, pose classes out."""

from __future__ import annotations

from typing import Annotated, Any

import anyio
from fastapi import APIRouter, Query, Request

from service.api.deps import (
    AUTHORISED,
    FocalDep,
    GridDep,
    LimiterDep,
    MetricsDep,
    NamedPredictorDep,
    PredictorDep,
    SettingsDep,
    StateDep,
    served_name,
)
from service.api.errors import ApiError
from service.api.schemas import ERROR_RESPONSES, PredictResponse, image_result_out
from service.api.state import ServiceState
from service.api.uploads import images_form, read_images
from service.core.cells import RegionGrid
from service.core.preprocess import ImageDecodeError, ImageTooLargeError
from service.metrics import Metrics
from service.pipeline.focal import KnownFocal
from service.pipeline.job import too_large_code
from service.pipeline.predictor import Predictor
from service.pipeline.results import Mode
from service.settings import Settings

router = APIRouter(tags=["predict"], dependencies=AUTHORISED)

#: OpenAPI of the body, which the endpoint reads itself (multipart or one raw image).
PREDICT_BODY: dict[str, Any] = {
    "requestBody": {
        "required": True,
        "content": {
            "multipart/form-data": images_form("One or many images (JPEG, PNG, WebP, BMP, GIF)."),
            "image/*": {"schema": {"type": "string", "format": "binary"}},
        },
    }
}

ModeQuery = Annotated[
    Mode,
    Query(
        description="whole: the image as is; sliding: best window of a grid; "
        "proposals: best object proposal (SPEC 9)."
    ),
]

SameCameraQuery = Annotated[
    bool,
    Query(
        description="The images are one camera's: one focal length fitted to the corners of "
        "all of them (whole mode, corner models, 2 or more images showing the object).",
    ),
]


async def answer(
    request: Request,
    state: ServiceState,
    predictor: Predictor,
    settings: Settings,
    limiter: anyio.CapacityLimiter,
    metrics: Metrics,
    mode: Mode,
    focal: KnownFocal | None,
    same_camera: bool,
    grid: RegionGrid | None,
) -> PredictResponse:
    """The one body of both predict routes: the request's images answered by `predictor` in
    a worker thread, counted, in the API's words; errors as ApiError. The options are checked
    before the body is read, the images' headers (their size limits) before the request
    waits for a job slot: each once."""
    try:
        options = predictor.options(mode, focal, same_camera, grid)
    except ValueError as exc:
        raise ApiError(422, "invalid_parameters", str(exc)) from None
    images = await read_images(request, settings.max_images)
    if same_camera and len(images) < 2:
        raise ApiError(422, "invalid_parameters", "same_camera: send 2 or more images")
    try:
        job = predictor.admit(images, options)
        prediction = await anyio.to_thread.run_sync(predictor.run, job, limiter=limiter)
    except ImageTooLargeError as exc:
        raise ApiError(413, too_large_code(exc), str(exc)) from None
    except ImageDecodeError as exc:
        raise ApiError(400, "undecodable_image", str(exc)) from None
    metrics.observe(mode, len(prediction.results), prediction.inference_s)
    results = [image_result_out(r) for r in prediction.results]
    return PredictResponse(model=served_name(state, predictor), mode=mode, results=results)


@router.post(
    "/v1/predict",
    response_model=PredictResponse,
    responses=ERROR_RESPONSES,
    openapi_extra=PREDICT_BODY,
    summary="Pose class of one or many images",
)
async def predict(
    request: Request,
    state: StateDep,
    predictor: PredictorDep,
    settings: SettingsDep,
    limiter: LimiterDep,
    metrics: MetricsDep,
    focal: FocalDep,
    grid: GridDep,
    mode: ModeQuery = "whole",
    same_camera: SameCameraQuery = False,
) -> PredictResponse:
    """Send images as multipart field `image` (repeat it for many) or one raw image body.

    All images of a request go through one batched network call.
    """
    return await answer(
        request, state, predictor, settings, limiter, metrics, mode, focal, same_camera, grid
    )


@router.post(
    "/v1/models/{name}/predict",
    response_model=PredictResponse,
    responses={**ERROR_RESPONSES, 404: {"description": "No model or camera of that name."}},
    openapi_extra=PREDICT_BODY,
    summary="Pose class of one or many images, with the model `name`",
)
async def predict_with(
    request: Request,
    state: StateDep,
    predictor: NamedPredictorDep,
    settings: SettingsDep,
    limiter: LimiterDep,
    metrics: MetricsDep,
    focal: FocalDep,
    grid: GridDep,
    mode: ModeQuery = "whole",
    same_camera: SameCameraQuery = False,
) -> PredictResponse:
    """As /v1/predict, answered by the served model `name` (see GET /v1/models)."""
    return await answer(
        request, state, predictor, settings, limiter, metrics, mode, focal, same_camera, grid
    )
