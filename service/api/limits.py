"""Request body limit as pure ASGI middleware: Content-Length checked up front, and the byte
count enforced while the body streams in (chunked uploads, lying Content-Length)."""

from __future__ import annotations

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.api.errors import ApiError, error_response


def _too_large(limit: int) -> ApiError:
    return ApiError(413, "payload_too_large", f"request body is larger than {limit} bytes")


class BodyLimitMiddleware:
    """Answer 413 when a request body exceeds `max_bytes`."""

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app, self.max_bytes = app, max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        length = dict(scope["headers"]).get(b"content-length")
        if length is not None and (not length.isdigit() or int(length) > self.max_bytes):
            err = _too_large(self.max_bytes) if length.isdigit() else None
            path = scope.get("path", "")
            response = (
                error_response(err.status, err.code, err.message, path=path)
                if err
                else error_response(400, "bad_request", "invalid Content-Length header", path=path)
            )
            await response(scope, receive, send)
            return
        seen = 0

        async def limited_receive() -> Message:
            nonlocal seen
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > self.max_bytes:
                    raise _too_large(self.max_bytes)  # -> the ApiError handler: 413 JSON
            return message

        await self.app(scope, limited_receive, send)
