"""Liveness, readiness and Prometheus metrics (never behind the API key)."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import Response

from service.api.deps import MetricsDep, StateDep, served_name
from service.api.errors import ApiError
from service.api.schemas import ERROR_RESPONSES, Status
from service.metrics import Metrics

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Status, response_model_exclude_none=True)
async def healthz() -> Status:
    """The process is up (liveness)."""
    return Status(status="ok")


@router.get("/readyz", response_model=Status, responses={503: ERROR_RESPONSES[503]})
async def readyz(state: StateDep) -> Status:
    """The default model is loaded (in every worker) and requests can be answered."""
    problem = state.not_ready()
    if problem is not None or state.predictor is None:
        raise ApiError(503, "not_ready", problem or state.problem)
    return Status(status="ready", model=served_name(state, state.predictor))


@router.get("/metrics", response_class=Response)
async def prometheus(metrics: MetricsDep) -> Response:
    """Prometheus text format."""
    return Response(metrics.render(), media_type=Metrics.content_type)
