"""The exceptions of the SDK: one per kind of failure the service (or the network) reports.

    PoseError                     any failure reported by the service or the transport
    ├── BadImageError             400  the service could not decode an image (or it was empty)
    ├── AuthError                 401  API key missing or wrong
    ├── NotFoundError             404  no such thing:
    │   ├── ModelNotFoundError         no served model of that name (the message lists them)
    │   └── CameraNotFoundError        no stored camera of that id (`cameras()` lists them)
    ├── CameraCorruptError        409  the stored camera's row is corrupt: delete_camera clears it
    ├── TooLargeError             413  too many bytes, too many pixels or too many images
    ├── UnsupportedMediaError     415  content type the service does not accept
    ├── InvalidRequestError       422  bad parameters (e.g. an unknown mode)
    ├── ServiceUnavailable        503  the model is not loaded (yet)
    └── PoseConnectionError       no HTTP answer at all: refused, DNS, timeout, broken connection

Input errors found before any request is sent (missing file, unsupported image object) are the
built-in `FileNotFoundError`, `TypeError` and `ValueError`.
"""

from __future__ import annotations

import httpx


class PoseError(Exception):
    """A failed call. `status` is the HTTP status (None without an answer), `code` the service's
    machine-readable error code and `message` its human-readable explanation."""

    def __init__(self, message: str, *, status: int | None = None, code: str = "error") -> None:
        super().__init__(message)
        self.status = status
        self.code = code
        self.message = message

    def __str__(self) -> str:
        where = f"HTTP {self.status} " if self.status is not None else ""
        return f"{where}{self.code}: {self.message}"

    def __repr__(self) -> str:
        fields = f"status={self.status!r}, code={self.code!r}, message={self.message!r}"
        return f"{type(self).__name__}({fields})"


class BadImageError(PoseError):
    """400: the service could not decode the image, or it was empty."""


class AuthError(PoseError):
    """401: the service requires an API key and the one sent is missing or wrong."""


class NotFoundError(PoseError):
    """404: the thing asked for does not exist (see the two subclasses)."""


class ModelNotFoundError(NotFoundError):
    """404: the service serves no model of that name; the message lists the served ones."""


class CameraNotFoundError(NotFoundError):
    """404: the service stores no camera of that id (`cameras()` lists the stored ones)."""


class CameraCorruptError(PoseError):
    """409 `camera_corrupt`: the service holds a row of that camera id that does not parse or
    validate (a hand edit, another version's, a damaged file); `delete_camera` clears it."""


class TooLargeError(PoseError):
    """413: the request or an image is too large (bytes, pixels) or holds too many images."""


class UnsupportedMediaError(PoseError):
    """415: the service does not accept the content type that was sent."""


class InvalidRequestError(PoseError):
    """422: the request's parameters are invalid (e.g. an unknown `mode`)."""


class ServiceUnavailable(PoseError):
    """503: the service is up but not ready (model not loaded)."""


class PoseConnectionError(PoseError):
    """No HTTP answer: connection refused, name not resolved, timeout or connection dropped.
    `attempts` is how many times the call was tried."""

    def __init__(self, message: str, *, attempts: int, code: str = "connection_failed") -> None:
        super().__init__(message, status=None, code=code)
        self.attempts = attempts


_BY_STATUS: dict[int, type[PoseError]] = {
    400: BadImageError,
    401: AuthError,
    404: ModelNotFoundError,
    413: TooLargeError,
    415: UnsupportedMediaError,
    422: InvalidRequestError,
    503: ServiceUnavailable,
}


def error_from_response(response: httpx.Response) -> PoseError:
    """Turn a non-2xx answer into the matching exception.

    The service answers errors as `{"error": {"code": str, "message": str}}`; anything else (a
    proxy's HTML page, FastAPI's `{"detail": ...}`) still gives a readable message.
    """
    code, message = f"http_{response.status_code}", response.reason_phrase or "error"
    try:
        body = response.json()
    except ValueError:
        body = None
    if isinstance(body, dict) and isinstance(body.get("error"), dict):
        code = str(body["error"].get("code", code))
        message = str(body["error"].get("message", message))
    elif isinstance(body, dict) and "detail" in body:
        message = str(body["detail"])
    elif response.text.strip():
        message = response.text.strip().splitlines()[0][:200]
    cls = _BY_STATUS.get(response.status_code, PoseError)
    if response.status_code == 404 and _about_a_camera(code, response):
        cls = CameraNotFoundError
    if response.status_code == 409 and code == "camera_corrupt":
        cls = CameraCorruptError
    return cls(message, status=response.status_code, code=code)


def _about_a_camera(code: str, response: httpx.Response) -> bool:
    """A 404 about a camera: its code says so (e.g. `camera_not_found`), or it answers a call
    on /v1/cameras/{id} without naming what is missing."""
    if "camera" in code:
        return True
    try:
        path = response.request.url.path
    except RuntimeError:  # a response built without its request
        return False
    return "/v1/cameras/" in path and "model" not in code
