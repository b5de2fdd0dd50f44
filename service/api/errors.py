"""Every error as JSON `{"error": {"code", "message"}}` with its HTTP status; no stack traces.
Under /v2 (the Open Inference Protocol) the protocol's shape instead: `{"error": "message"}`.

Unexpected exceptions are logged here (with traceback) and answered 500 `internal_error` by
`CrashMiddleware`, which keeps the client's keep-alive connection usable (Starlette's own 500
re-raises the exception to the server, which then drops the connection without saying
`Connection: close`, and the client's next request on it is reset).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.requests import ClientDisconnect
from starlette.types import ASGIApp, Message, Receive, Scope, Send

log = logging.getLogger("uvicorn.error.pose")  # printed by uvicorn's handlers

_CODES = {
    400: "bad_request",
    401: "unauthorized",
    404: "not_found",
    405: "method_not_allowed",
    413: "payload_too_large",
    415: "unsupported_media_type",
    422: "invalid_parameters",
    503: "not_ready",
}


class ApiError(Exception):
    """An answer other than 2xx, raised anywhere below an endpoint."""

    def __init__(
        self, status: int, code: str, message: str, headers: dict[str, str] | None = None
    ) -> None:
        super().__init__(message)
        self.status, self.code, self.message, self.headers = status, code, message, headers


def is_v2(path: str) -> bool:
    """True for the Open Inference Protocol's paths."""
    return path == "/v2" or path.startswith("/v2/")


def error_response(
    status: int,
    code: str,
    message: str,
    headers: Mapping[str, str] | None = None,
    path: str = "",
) -> JSONResponse:
    """The error answer; `path` picks the shape (/v2: the protocol's `{"error": message}`)."""
    body: dict[str, object] = {"error": {"code": code, "message": message}}
    if is_v2(path):
        body = {"error": message}
    return JSONResponse(body, status, headers=headers)


class CrashMiddleware:
    """An exception no handler answered -> logged with its traceback, answered 500
    `internal_error`, and not passed on to the server: the connection stays usable. When the
    answer had already begun, only closing the connection can end it: the exception goes on
    to the server, which does that."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = False

        async def send_tracked(message: Message) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, receive, send_tracked)
        except Exception as exc:
            log.exception("unhandled error on %s %s", scope["method"], scope["path"], exc_info=exc)
            if started:
                raise
            response = error_response(
                500, "internal_error", "internal server error (logged)", path=scope["path"]
            )
            await response(scope, receive, send)


def _validation_message(exc: RequestValidationError) -> str:
    parts = []
    for err in exc.errors():
        where = ".".join(str(p) for p in err.get("loc", ()) if p not in ("query", "body"))
        parts.append(f"{where}: {err.get('msg', 'invalid')}" if where else err.get("msg", ""))
    return "; ".join(parts) or "invalid request"


def install_error_handlers(app: FastAPI) -> None:
    """Route FastAPI/Starlette errors and crashes through the one JSON error shape."""

    async def api_error(request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, ApiError)
        return error_response(exc.status, exc.code, exc.message, exc.headers, request.url.path)

    async def http_error(request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, StarletteHTTPException)
        code = _CODES.get(exc.status_code, "error")
        path = request.url.path
        return error_response(exc.status_code, code, str(exc.detail), exc.headers, path)

    async def validation_error(request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, RequestValidationError)
        message = _validation_message(exc)
        return error_response(422, "invalid_parameters", message, path=request.url.path)

    async def gone(request: Request, _: Exception) -> JSONResponse:
        path = request.url.path
        log.info("client left during %s %s before sending its body", request.method, path)
        message = "the client closed the connection"
        return error_response(400, "client_disconnected", message, path=path)

    async def crash(request: Request, exc: Exception) -> JSONResponse:
        path = request.url.path
        log.exception("unhandled error on %s %s", request.method, path, exc_info=exc)
        return error_response(500, "internal_error", "internal server error (logged)", path=path)

    app.add_exception_handler(ApiError, api_error)
    app.add_exception_handler(StarletteHTTPException, http_error)
    app.add_exception_handler(RequestValidationError, validation_error)
    app.add_exception_handler(ClientDisconnect, gone)
    app.add_exception_handler(Exception, crash)
