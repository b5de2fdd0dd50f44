"""`/v1/cameras`: cameras the service learns, from their intrinsics or from photos of the object
(docs/pose.md); stored in SQLite (`service/cameras/store.py`)."""

from __future__ import annotations

from typing import Annotated, Any

import anyio
from fastapi import APIRouter, Query, Request, Response
from pydantic import ValidationError

from service.api.deps import (
    AUTHORISED,
    CamerasDep,
    LimiterDep,
    SettingsDep,
    StateDep,
    get_predictor,
)
from service.api.errors import ApiError
from service.api.schemas import ERROR_RESPONSES, CameraList, ErrorResponse
from service.api.uploads import images_form, read_images
from service.cameras.learning import MIN_PHOTOS, learn_into
from service.cameras.schema import CameraIn, CameraOut
from service.cameras.store import (
    CameraCorrupt,
    CameraNotFound,
    CameraStoreError,
    CameraStoreFull,
)
from service.core.preprocess import ImageDecodeError, ImageTooLargeError
from service.pipeline.job import too_large_code

router = APIRouter(tags=["cameras"], dependencies=AUTHORISED)


CAMERA_BODY: dict[str, Any] = {
    "requestBody": {
        "required": True,
        "content": {
            "application/json": {"schema": CameraIn.model_json_schema()},
            "multipart/form-data": images_form(
                f"{MIN_PHOTOS} or more photos of the object by the camera, all of one size."
            ),
        },
    }
}


def store_error(exc: Exception) -> ApiError:
    """The answer to an error of the camera store: 404 unknown id, 409 store full or the
    camera's row corrupt (DELETE clears it), 503 the store cannot be used."""
    if isinstance(exc, CameraNotFound):
        return ApiError(404, "camera_not_found", str(exc))
    if isinstance(exc, CameraStoreFull):
        return ApiError(409, "camera_store_full", str(exc))
    if isinstance(exc, CameraCorrupt):
        return ApiError(409, "camera_corrupt", str(exc))
    return ApiError(503, "camera_store_unavailable", str(exc))


#: OpenAPI of the answers of a route that reads one stored camera.
CAMERA_RESPONSES: dict[int | str, dict[str, Any]] = {
    **ERROR_RESPONSES,
    409: {
        "model": ErrorResponse,
        "description": "camera_corrupt: the camera's stored row does not parse or validate "
        "(DELETE /v1/cameras/{id} clears it).",
    },
}


@router.post(
    "/v1/cameras",
    response_model=CameraOut,
    status_code=201,
    responses={**ERROR_RESPONSES, 409: {"description": "The camera store is full."}},
    openapi_extra=CAMERA_BODY,
    summary="Store a camera: its intrinsics (JSON) or photos of the object by it (multipart)",
)
async def create_camera(
    request: Request,
    cameras: CamerasDep,
    state: StateDep,
    settings: SettingsDep,
    limiter: LimiterDep,
    name: Annotated[str | None, Query(max_length=100)] = None,
    model: Annotated[
        str | None,
        Query(
            description="Photos: the corner model that finds the object (default: the "
            "default model)."
        ),
    ] = None,
) -> CameraOut:
    """JSON `{"fx": ..., "width": ..., "height": ...}` (docs/pose.md), or multipart `image`
    fields: 3 or more photos of the object, one camera, one size; `?model=` picks the
    corner model that finds the object (default: the default model). Intrinsics need no
    model: they are stored while the models load too."""
    kind = request.headers.get("content-type", "").split(";")[0].strip().lower()
    try:
        if kind == "application/json":
            given = _intrinsics(await request.body())
            return await anyio.to_thread.run_sync(cameras.create_from, given, name)
        predictor = await get_predictor(state, model)
        images = await read_images(request, settings.max_images)
        return await anyio.to_thread.run_sync(
            learn_into, cameras, predictor, images, name, limiter=limiter
        )
    except (CameraStoreFull, CameraStoreError) as exc:
        raise store_error(exc) from None
    except ImageTooLargeError as exc:
        raise ApiError(413, too_large_code(exc), str(exc)) from None
    except ImageDecodeError as exc:
        raise ApiError(400, "undecodable_image", str(exc)) from None
    except ValueError as exc:
        raise ApiError(422, "camera_not_learned", str(exc)) from None


def _intrinsics(body: bytes) -> CameraIn:
    """The JSON body of a camera's intrinsics, or 422 `invalid_camera` saying what is wrong."""
    try:
        return CameraIn.model_validate_json(body)
    except ValidationError as exc:
        problems = "; ".join(
            f"{'.'.join(str(p) for p in e['loc']) or 'body'}: {e['msg']}" for e in exc.errors()
        )
        raise ApiError(422, "invalid_camera", problems) from None


@router.get(
    "/v1/cameras",
    response_model=CameraList,
    responses=ERROR_RESPONSES,
    summary="The stored cameras, newest first (rows that do not parse or validate are left "
    "out and logged)",
)
async def list_cameras(cameras: CamerasDep) -> CameraList:
    try:
        return CameraList(cameras=await anyio.to_thread.run_sync(cameras.list))
    except CameraStoreError as exc:
        raise store_error(exc) from None


@router.get(
    "/v1/cameras/{camera_id}",
    response_model=CameraOut,
    responses=CAMERA_RESPONSES,
    summary="One stored camera",
)
async def get_camera(camera_id: str, cameras: CamerasDep) -> CameraOut:
    try:
        return await anyio.to_thread.run_sync(cameras.get, camera_id)
    except (CameraNotFound, CameraCorrupt, CameraStoreError) as exc:
        raise store_error(exc) from None


@router.delete(
    "/v1/cameras/{camera_id}",
    status_code=204,
    responses=ERROR_RESPONSES,
    summary="Forget a stored camera (a corrupt one too)",
)
async def delete_camera(camera_id: str, cameras: CamerasDep) -> Response:
    try:
        await anyio.to_thread.run_sync(cameras.delete, camera_id)
    except (CameraNotFound, CameraStoreError) as exc:
        raise store_error(exc) from None
    return Response(status_code=204)
