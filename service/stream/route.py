"""`WS /v1/stream?mode=whole|sliding|proposals&smooth=F&model=NAME&fx=F&camera=ID&regions=G`:
live frames in, answers out (the protocol: `service/stream/protocol.py` and docs/live.md)."""

from __future__ import annotations

import logging
from weakref import WeakKeyDictionary

import anyio
from fastapi import APIRouter, WebSocket
from starlette.websockets import WebSocketDisconnect

from service.api.deps import served_name, unavailable
from service.api.state import ServiceState
from service.cameras.store import CameraCorrupt, CameraNotFound, CameraStoreError, known_focal
from service.metrics import Metrics
from service.pipeline.focal import KnownFocal, fx_problem
from service.pipeline.model import ModelLoadError
from service.pipeline.predictor import Predictor
from service.pipeline.registry import UnknownModel
from service.stream.protocol import (
    CloseCode,
    StreamMetrics,
    StreamOptions,
    StreamRefused,
    StreamSession,
    authorise,
    parse_options,
    refuse,
)

router = APIRouter(tags=["stream"])
log = logging.getLogger("uvicorn.error.pose")  # printed by uvicorn's handlers

_metrics: WeakKeyDictionary[Metrics, StreamMetrics] = WeakKeyDictionary()


def stream_metrics(metrics: Metrics) -> StreamMetrics:
    """The stream's series in the app's registry, created on first use."""
    if metrics not in _metrics:
        _metrics[metrics] = StreamMetrics(metrics)
    return _metrics[metrics]


async def find_predictor(state: ServiceState, name: str | None) -> Predictor:
    """The predictor of model `name` (None: the default one; loaded first if it is not), or
    StreamRefused 1013/4404."""
    if name is None:
        predictor = state.models.default(count=True)
        if predictor is None:
            raise StreamRefused(CloseCode.TRY_AGAIN_LATER, "not_ready", state.problem)
        return predictor
    try:
        return await state.predictor_of(name)
    except ModelLoadError as exc:
        raise StreamRefused(
            CloseCode.TRY_AGAIN_LATER, "model_unavailable", unavailable(name, exc)
        ) from None
    except UnknownModel as exc:
        if not state.loaded:
            raise StreamRefused(CloseCode.TRY_AGAIN_LATER, "not_ready", state.problem) from None
        known = ", ".join(exc.known) or "none"
        raise StreamRefused(
            CloseCode.NOT_FOUND, "model_not_found", f"no model named {name!r}; served: {known}"
        ) from None


async def stream_focal(state: ServiceState, options: StreamOptions) -> KnownFocal | None:
    """The focal length of `fx=` or of the stored camera `camera=` (StreamRefused 4422 for an
    fx out of its range, 4404 for an unknown id, 4409 for a corrupt row, 1013 when the store
    cannot be read)."""
    if options.camera is None:
        if options.fx is None:
            return None
        problem = fx_problem(options.fx)  # the range, checked once: here
        if problem is not None:
            raise StreamRefused(CloseCode.INVALID_PARAMETERS, "invalid_parameters", problem)
        return KnownFocal(options.fx, "query")
    try:
        camera = await anyio.to_thread.run_sync(state.cameras.get, options.camera, "stream")
        return known_focal(camera)
    except CameraNotFound as exc:
        raise StreamRefused(CloseCode.NOT_FOUND, "camera_not_found", str(exc)) from None
    except CameraCorrupt as exc:
        raise StreamRefused(CloseCode.CONFLICT, "camera_corrupt", str(exc)) from None
    except CameraStoreError as exc:
        raise StreamRefused(
            CloseCode.TRY_AGAIN_LATER, "camera_store_unavailable", str(exc)
        ) from None


@router.websocket("/v1/stream")
async def stream(websocket: WebSocket) -> None:
    """Answer each binary frame (JPEG/PNG) with its pose class, in order (docs/live.md)."""
    state: ServiceState = websocket.app.state.pose
    settings = state.settings
    await websocket.accept()
    key = settings.api_key.get_secret_value() if settings.api_key else None
    try:
        await authorise(websocket, key)
        options = parse_options(websocket.query_params)
        predictor = await find_predictor(state, options.model)
        focal = await stream_focal(state, options)
        problem = predictor.focal_problem(options.mode, focal)
        if problem is not None:
            raise StreamRefused(CloseCode.INVALID_PARAMETERS, "invalid_parameters", problem)
    except StreamRefused as refused:
        await refuse(websocket, refused)
        return
    except WebSocketDisconnect:
        return
    except Exception:  # a bug: logged, and the client gets a close code, not a dropped socket
        log.exception("stream setup failed (%s)", websocket.url.path)
        message = "internal server error (logged)"
        await refuse(websocket, StreamRefused(CloseCode.INTERNAL_ERROR, "internal_error", message))
        return
    session = StreamSession(
        websocket,
        predictor,
        options,
        state.jobs,
        stream_metrics(state.metrics),
        settings.max_upload_bytes,
        focal,
        served_name(state, predictor),
    )
    await session.run()
