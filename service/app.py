"""The HTTP service: FastAPI over one shared onnxruntime session.

`uvicorn service.app:app` serves with settings from the environment (`POSE_*`); `create_app`
builds an app from explicit settings (the `planar-pose-serve` command, tests). The routes live
in `service/api/routes/` (one APIRouter per concern), their dependencies in `service/api/deps.py`.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

import cv2
from fastapi import APIRouter, FastAPI
from fastapi.middleware.cors import CORSMiddleware
from pydantic import ValidationError

from service.api.drain import DrainMiddleware, hold_back_sigterm
from service.api.errors import CrashMiddleware, install_error_handlers
from service.api.limits import BodyLimitMiddleware
from service.api.redact import install as redact_secrets_in_logs
from service.api.request_metrics import MetricsMiddleware
from service.api.routes import cameras, health, model, predict, v2, web
from service.api.state import ServiceState
from service.settings import Settings
from service.stream import route as stream

#: The routers served, in order; adding one is one line here.
ROUTERS: list[APIRouter] = [
    predict.router,
    cameras.router,
    model.router,
    health.router,
    v2.health,
    v2.router,
    stream.router,
]


@asynccontextmanager
async def lifespan(app: FastAPI) -> AsyncIterator[None]:
    """List the models and load the default one, then serve and follow reloads. uvicorn
    accepts connections only once this startup is done, so a worker (re)started next to
    others on the shared socket takes no request before its default model is loaded."""
    state: ServiceState = app.state.pose
    hold_back_sigterm(state.drain, asyncio.get_running_loop())  # POSE_DRAIN_S
    cameras = asyncio.create_task(asyncio.to_thread(state.cameras.check_at_start))  # logged
    await asyncio.to_thread(state.load)
    follow = asyncio.create_task(state.follow())
    try:
        yield
    finally:
        follow.cancel()
        await cameras
        state.close()


def create_app(settings: Settings | None = None) -> FastAPI:
    """The FastAPI app: state, routers, error handlers and middleware (wiring only)."""
    settings = settings or Settings()
    redact_secrets_in_logs()  # ?api_key= and the like never reach a log line
    # OpenCV would log every refused upload to stderr; the client's 400 already says it.
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_FATAL)
    app = FastAPI(
        title="planar-pose",
        summary="Coarse camera pose region of a known planar object from one photograph.",
        version="1",
        lifespan=lifespan,
        docs_url=None,  # self-hosted docs pages: service/api/routes/web.py
        redoc_url=None,
    )
    app.state.pose = state = ServiceState(settings)
    install_error_handlers(app)
    for router in ROUTERS:
        app.include_router(router)
    web.install(app)  # the page at /, /static, /docs + /redoc with packaged assets
    routes = frozenset(
        getattr(r, "path", "") for r in [*app.routes, *(r for x in ROUTERS for r in x.routes)]
    )
    app.add_middleware(BodyLimitMiddleware, max_bytes=settings.max_upload_bytes)
    app.add_middleware(DrainMiddleware, drain=state.drain)
    if settings.cors_origins:
        app.add_middleware(
            CORSMiddleware,
            allow_origins=settings.cors_origins,
            allow_methods=["GET", "POST"],
            allow_headers=["Authorization", "X-API-Key", "Content-Type"],
        )
    app.add_middleware(CrashMiddleware)  # a 500 that leaves the connection usable
    app.add_middleware(MetricsMiddleware, metrics=state.metrics, routes=routes)
    return app


def __getattr__(name: str) -> FastAPI:
    """`service.app:app` (for `uvicorn service.app:app`): built from POSE_* on first use."""
    if name != "app":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    try:
        application = create_app()
    except ValidationError as exc:  # bad POSE_* variables
        raise SystemExit(f"error: invalid settings (POSE_* environment):\n{exc}") from None
    globals()["app"] = application
    return application
