"""Typed FastAPI dependencies reading `request.app.state.pose` (tests override them with
`app.dependency_overrides[get_predictor] = ...`). All are `async def`: FastAPI would run a
plain `def` dependency in a worker thread, a thread hop per dependency per request."""

from __future__ import annotations

import secrets
from typing import Annotated

import anyio
from fastapi import Depends, Query, Request

from service.api.errors import ApiError
from service.api.state import ServiceState
from service.cameras.store import (
    CameraCorrupt,
    CameraNotFound,
    CameraStore,
    CameraStoreError,
    known_focal,
)
from service.core.cells import RegionGrid
from service.metrics import Metrics
from service.pipeline.focal import FX_MAX_PX, FX_MIN_PX, KnownFocal
from service.pipeline.model import ModelLoadError
from service.pipeline.predictor import Predictor
from service.pipeline.registry import ModelRegistry, UnknownModel
from service.settings import Settings


async def get_state(request: Request) -> ServiceState:
    """The app's shared state (set by `create_app`)."""
    state: ServiceState = request.app.state.pose
    return state


StateDep = Annotated[ServiceState, Depends(get_state)]


async def get_settings(state: StateDep) -> Settings:
    return state.settings


async def get_metrics(state: StateDep) -> Metrics:
    return state.metrics


async def get_limiter(state: StateDep) -> anyio.CapacityLimiter:
    """At most `Settings.inference_jobs` inference jobs at once; more requests queue."""
    return state.jobs


async def get_predictor(
    state: StateDep,
    model: Annotated[
        str | None,
        Query(description="A served model's name (GET /v1/models); default: the default model."),
    ] = None,
) -> Predictor:
    """The predictor of `?model=` (404 listing the known names) or of the default model;
    503 `not_ready` with the reason while it is not loaded."""
    if model is not None:
        return await get_named_predictor(model, state)
    predictor = state.models.default(count=True)
    if predictor is None:
        raise ApiError(503, "not_ready", state.problem)
    return predictor


async def get_models(state: StateDep) -> ModelRegistry:
    return state.models


async def get_named_predictor(name: str, state: StateDep) -> Predictor:
    """The predictor of the model `name` (path parameter), loaded first if it is not; 404
    listing the known names, 503 `model_unavailable` when its graph does not load."""
    try:
        return await state.predictor_of(name)
    except UnknownModel as exc:
        if not state.loaded:
            raise ApiError(503, "not_ready", state.problem) from None
        known = ", ".join(exc.known) or "none"
        raise ApiError(
            404, "model_not_found", f"no model named {name!r}; served: {known}"
        ) from None
    except ModelLoadError as exc:
        raise ApiError(503, "model_unavailable", unavailable(name, exc)) from None


def unavailable(name: str, exc: ModelLoadError) -> str:
    """The message of a served model whose graph does not load."""
    return f"model {name!r} could not be loaded: {exc} (replace the file, then reload)"


def served_name(state: ServiceState, predictor: Predictor) -> str:
    """The name `predictor` is served under (its file's stem: the name in URLs and in every
    answer's `model`), not its card's name, which a copied or renamed file keeps."""
    for name, file in state.models.entries().items():
        if file.path == predictor.model.path:
            return name
    return predictor.model.path.stem  # reloaded away while the request ran


SettingsDep = Annotated[Settings, Depends(get_settings)]
MetricsDep = Annotated[Metrics, Depends(get_metrics)]
LimiterDep = Annotated[anyio.CapacityLimiter, Depends(get_limiter)]
PredictorDep = Annotated[Predictor, Depends(get_predictor)]
NamedPredictorDep = Annotated[Predictor, Depends(get_named_predictor)]
ModelsDep = Annotated[ModelRegistry, Depends(get_models)]


async def get_cameras(state: StateDep) -> CameraStore:
    return state.cameras


CamerasDep = Annotated[CameraStore, Depends(get_cameras)]


async def stored_camera(cameras: CameraStore, camera_id: str) -> KnownFocal:
    """The stored camera `camera_id`'s intrinsics (read in a worker thread); 404 unknown,
    409 `camera_corrupt` its row unusable, 503 store unavailable."""
    try:
        return known_focal(await anyio.to_thread.run_sync(cameras.get, camera_id, "predict"))
    except CameraNotFound as exc:
        raise ApiError(404, "camera_not_found", str(exc)) from None
    except CameraCorrupt as exc:
        raise ApiError(409, "camera_corrupt", str(exc)) from None
    except CameraStoreError as exc:
        raise ApiError(503, "camera_store_unavailable", str(exc)) from None


async def get_focal(
    cameras: CamerasDep,
    fx: Annotated[
        float | None,
        Query(
            description="The camera's focal length fx in pixels of the uploaded images "
            "(camera matrix [0, 0] of a calibration at that size; mode=whole, corner models): "
            "the class and the pose use it instead of estimating it. Unset: estimated.",
            ge=FX_MIN_PX,
            le=FX_MAX_PX,
            allow_inf_nan=False,
        ),
    ] = None,
    camera: Annotated[
        str | None,
        Query(
            description="A stored camera's id (POST /v1/cameras): its intrinsics, scaled to "
            "each image's size, instead of estimating them.",
            max_length=64,
        ),
    ] = None,
) -> KnownFocal | None:
    """The focal length the request knows: `fx=` or the stored camera `camera=` (422 both)."""
    if fx is not None and camera is not None:
        raise ApiError(422, "invalid_parameters", "fx and camera: give one of them")
    if camera is not None:
        return await stored_camera(cameras, camera)
    return None if fx is None else KnownFocal(fx, "query")


async def get_grid(
    settings: SettingsDep,
    regions: Annotated[
        str | None,
        Query(
            description="Finer regions: AxE or AxExD1,D2,... (azimuth sectors x elevation "
            "bands x distance splits in cm, docs/pose.md); the answer's `cell`. Default: "
            "POSE_REGIONS (unset: none).",
            max_length=200,
        ),
    ] = None,
) -> RegionGrid | None:
    """The grid of `regions=` (else the settings'), 422 for one that does not parse."""
    text = regions or settings.regions
    if not text:
        return None
    try:
        return RegionGrid.parse(text)
    except ValueError as exc:
        raise ApiError(422, "invalid_parameters", str(exc)) from None


FocalDep = Annotated[KnownFocal | None, Depends(get_focal)]
GridDep = Annotated[RegionGrid | None, Depends(get_grid)]


async def authorise(request: Request, settings: SettingsDep) -> None:
    """401 unless the request carries the API key (`Authorization: Bearer` or `X-API-Key`),
    when `POSE_API_KEY` is set."""
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


#: Route dependency list for endpoints behind the API key.
AUTHORISED = [Depends(authorise)]
