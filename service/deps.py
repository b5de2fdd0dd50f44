"""Typed FastAPI dependencies reading `request.app.state.pose` (tests override them with
`app.dependency_overrides[get_predictor] = ...`). All are `async def`: FastAPI would run a
plain `def` dependency in a worker thread, a thread hop per dependency per request."""

from __future__ import annotations

import secrets
from typing import Annotated

import anyio
from fastapi import Depends, Query, Request

from service.errors import ApiError
from service.metrics import Metrics
from service.predictor import Predictor
from service.registry import ModelRegistry, UnknownModel
from service.settings import Settings
from service.state import ServiceState


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
    predictor = state.predictor
    if predictor is None:
        raise ApiError(503, "not_ready", state.problem)
    return predictor


async def get_models(state: StateDep) -> ModelRegistry:
    return state.models


async def get_named_predictor(name: str, state: StateDep) -> Predictor:
    """The predictor of the model `name` (path parameter), 404 listing the known names."""
    try:
        return state.models.get(name)
    except UnknownModel as exc:
        if not state.loaded:
            raise ApiError(503, "not_ready", state.problem) from None
        known = ", ".join(exc.known) or "none"
        raise ApiError(
            404, "model_not_found", f"no model named {name!r}; served: {known}"
        ) from None


SettingsDep = Annotated[Settings, Depends(get_settings)]
MetricsDep = Annotated[Metrics, Depends(get_metrics)]
LimiterDep = Annotated[anyio.CapacityLimiter, Depends(get_limiter)]
PredictorDep = Annotated[Predictor, Depends(get_predictor)]
NamedPredictorDep = Annotated[Predictor, Depends(get_named_predictor)]
ModelsDep = Annotated[ModelRegistry, Depends(get_models)]


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
