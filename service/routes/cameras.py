"""`/v1/cameras`: cameras the service learns, from their intrinsics or from photos of the object
(docs/pose.md); stored in SQLite (`service/cameras.py`)."""

from __future__ import annotations

from typing import Annotated, Any

import anyio
from fastapi import APIRouter, Query, Request, Response
from pydantic import ValidationError

from service.cameras import (
    CameraCorrupt,
    CameraNotFound,
    CameraStore,
    CameraStoreError,
    CameraStoreFull,
)
from service.core.frame import object_corners
from service.core.pose import fit_focal
from service.core.preprocess import ImageDecodeError, ImageTooLargeError, landscape_pixels
from service.deps import (
    AUTHORISED,
    CamerasDep,
    LimiterDep,
    SettingsDep,
    StateDep,
    get_predictor,
)
from service.errors import ApiError
from service.predictor import Predictor, too_large_code
from service.schemas import ERROR_RESPONSES, CameraIn, CameraList, CameraOut, ErrorResponse
from service.uploads import read_images

router = APIRouter(tags=["cameras"], dependencies=AUTHORISED)

#: Photos of the object a camera is learned from, at least.
MIN_PHOTOS = 3
#: The widest range of focal lengths (hi - lo) / fx the photos may leave: wider, they do not
#: pin it (views too close to head-on, or too few) and the camera is not stored.
MAX_FX_SPREAD = 0.5

CAMERA_BODY: dict[str, Any] = {
    "requestBody": {
        "required": True,
        "content": {
            "application/json": {"schema": CameraIn.model_json_schema()},
            "multipart/form-data": {
                "schema": {
                    "type": "object",
                    "properties": {
                        "image": {
                            "type": "array",
                            "items": {"type": "string", "format": "binary"},
                            "description": f"{MIN_PHOTOS} or more photos of the object by the "
                            "camera, all of one size.",
                        }
                    },
                    "required": ["image"],
                }
            },
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


async def _stored(cameras: CameraStore, fields: dict[str, Any]) -> CameraOut:
    try:
        return await anyio.to_thread.run_sync(cameras.create, fields)
    except (CameraStoreFull, CameraStoreError) as exc:
        raise store_error(exc) from None


def learn(predictor: Predictor, images: list[tuple[str | None, bytes]]) -> dict[str, Any]:
    """Photos of the object by one camera -> the camera's fields (fx fitted to the corners the
    network finds in them, `fit_focal`); ValueError saying why it cannot be learned."""
    size_cm = predictor.model.object_size_cm
    if size_cm is None or predictor.model.corners_name is None:
        raise ValueError(f"model {predictor.model.name} gives no corners: pick a corner model")
    prediction = predictor.predict(images, "whole")
    found = [
        ((r.image_size[0], r.image_size[1]), q)
        for r, q in zip(prediction.results, prediction.pinhole, strict=True)
        if q is not None and r.image_size is not None
    ]
    if len(found) < MIN_PHOTOS:
        raise ValueError(
            f"the object was found in {len(found)} of {len(images)} photos; "
            f"{MIN_PHOTOS} or more are needed"
        )
    w, h = max(found[0][0]), min(found[0][0])  # landscape: portraits are the camera turned
    odd = sorted({size for size, _ in found if sorted(size) != [h, w]})
    if odd:
        raise ValueError(
            f"photos of {w}x{h} and of {', '.join(f'{a}x{b}' for a, b in odd)}: "
            "send one camera's photos, all of one size"
        )
    # a portrait is the camera turned: its corners turned back to landscape (fx and a centred
    # principal point stay)
    views = [landscape_pixels(q, size) for size, q in found]
    fit = fit_focal(views, object_corners(*size_cm, z=True), (w, h))
    used = int(fit.used.sum())
    spread = (fit.interval[1] - fit.interval[0]) / fit.fx
    if used < MIN_PHOTOS or spread > MAX_FX_SPREAD:
        raise ValueError(
            f"the {used} photos that fit leave fx between {fit.interval[0]:.0f} and "
            f"{fit.interval[1]:.0f} px: add photos that view the object obliquely "
            "(tilted 20-50 degrees), from several sides"
        )
    return {
        "fx": round(fit.fx, 3),
        "width": w,
        "height": h,
        "source": "photos",
        "photos_used": used,
        "residual_px": round(fit.residual_px, 3),
        "fx_range": [round(v, 3) for v in fit.interval],
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
    if kind == "application/json":
        try:
            given = CameraIn.model_validate_json(await request.body())
        except ValidationError as exc:
            problems = "; ".join(
                f"{'.'.join(str(p) for p in e['loc']) or 'body'}: {e['msg']}" for e in exc.errors()
            )
            raise ApiError(422, "invalid_camera", problems) from None
        fields = given.model_dump()
        fields["name"] = fields["name"] or name
        return await _stored(
            cameras, {**fields, "source": "intrinsics", "photos_used": 0, "residual_px": None}
        )
    predictor = await get_predictor(state, model)
    images = await read_images(request, settings.max_images)
    try:
        fields = await anyio.to_thread.run_sync(learn, predictor, images, limiter=limiter)
    except ImageTooLargeError as exc:
        raise ApiError(413, too_large_code(exc), str(exc)) from None
    except ImageDecodeError as exc:
        raise ApiError(400, "undecodable_image", str(exc)) from None
    except ValueError as exc:
        raise ApiError(422, "camera_not_learned", str(exc)) from None
    return await _stored(cameras, {**fields, "name": name})


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
