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
from service.api.schemas import ERROR_RESPONSES, Mode, PredictResponse
from service.api.uploads import read_images
from service.cameras.store import KnownFocal
from service.core.cells import RegionGrid
from service.core.preprocess import ImageDecodeError, ImageTooLargeError
from service.pipeline.predictor import Prediction, Predictor, too_large_code

router = APIRouter(tags=["predict"], dependencies=AUTHORISED)

#: OpenAPI of the body, which the endpoint reads itself (multipart or one raw image).
PREDICT_BODY: dict[str, Any] = {
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


async def run_prediction(
    request: Request,
    predictor: Predictor,
    mode: Mode,
    max_images: int,
    limiter: anyio.CapacityLimiter,
    focal: KnownFocal | None = None,
    same_camera: bool = False,
    grid: RegionGrid | None = None,
) -> Prediction:
    """Read the request's images and classify them in a worker thread; errors as ApiError."""
    problem = predictor.focal_problem(mode, focal, same_camera)
    if problem is not None:
        raise ApiError(422, "invalid_parameters", problem)
    images = await read_images(request, max_images)
    if same_camera and len(images) < 2:
        raise ApiError(422, "invalid_parameters", "same_camera: send 2 or more images")
    try:
        predictor.check_pixels(images, mode)  # from the headers, before waiting for a job slot
        return await anyio.to_thread.run_sync(
            predictor.predict, images, mode, focal, same_camera, grid, limiter=limiter
        )
    except ImageTooLargeError as exc:
        raise ApiError(413, too_large_code(exc), str(exc)) from None
    except ImageDecodeError as exc:
        raise ApiError(400, "undecodable_image", str(exc)) from None


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
    prediction = await run_prediction(
        request, predictor, mode, settings.max_images, limiter, focal, same_camera, grid
    )
    metrics.observe(mode, len(prediction.results), prediction.inference_s)
    name = served_name(state, predictor)
    return PredictResponse(model=name, mode=mode, results=prediction.results)


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
    prediction = await run_prediction(
        request, predictor, mode, settings.max_images, limiter, focal, same_camera, grid
    )
    metrics.observe(mode, len(prediction.results), prediction.inference_s)
    name = served_name(state, predictor)
    return PredictResponse(model=name, mode=mode, results=prediction.results)
