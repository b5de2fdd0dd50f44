"""What the sync and async clients share: settings, request building, retry decisions and
response parsing. Only the act of sending (and sleeping between attempts) differs between them.
"""

from __future__ import annotations

import math
import numbers
import random
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeVar

import httpx
from pydantic import BaseModel, ValidationError

from .errors import PoseConnectionError, PoseError, error_from_response
from .images import ImageInput, is_single_image, to_upload
from .models import (
    Camera,
    CameraIntrinsics,
    CameraList,
    Mode,
    ModelCard,
    ModelList,
    Prediction,
    PredictResponse,
)

DEFAULT_TIMEOUT_S = 30.0
#: What the service accepts as a model name in a URL.
MODEL_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")
#: What a camera id looks like (the service's are e.g. "c-3f2a9b1c"); it goes into URLs too.
CAMERA_ID = MODEL_NAME
#: The shape of `regions=`: A azimuth sectors x E elevation bands [x distance splits D1,D2,...
#: in cm]; the service judges the numbers (limits, increasing splits).
REGIONS = re.compile(r"[0-9]{1,3}x[0-9]{1,3}(x[0-9.,eE+]+)?")
#: Transport errors raised before the request left: retrying cannot repeat a change.
_NOT_SENT = (httpx.ConnectError, httpx.ConnectTimeout, httpx.PoolTimeout)

M = TypeVar("M", bound=BaseModel)


@dataclass(frozen=True)
class RetryPolicy:
    """Retry a call `retries` times after the first attempt when there was no answer at all
    (connection refused, timeout, dropped connection) or the answer was 503/502/504.

    The wait before retry n (0-based) is min(backoff_max, backoff * 2**n) seconds times a
    random factor in [0.5, 1] (jitter, so many clients do not retry in lockstep); a
    `Retry-After` header in seconds raises it, still capped at backoff_max.
    """

    retries: int = 2
    backoff: float = 0.25
    backoff_max: float = 5.0
    statuses: frozenset[int] = field(default=frozenset({502, 503, 504}))

    def __post_init__(self) -> None:
        if self.retries < 0 or self.backoff < 0 or self.backoff_max < 0:
            raise ValueError("retries, backoff and backoff_max must be >= 0")

    def delay(self, retry: int, retry_after: float | None = None) -> float:
        """Seconds to wait before retry number `retry` (0-based)."""
        wait = min(self.backoff_max, self.backoff * 2.0**retry) * random.uniform(0.5, 1.0)
        if retry_after is not None:
            wait = max(wait, min(retry_after, self.backoff_max))
        return wait


class ClientCore:
    """Settings and the transport-free half of a client (sans-IO)."""

    def __init__(
        self,
        base_url: str,
        api_key: str | None,
        timeout: float | httpx.Timeout,
        retry: RetryPolicy,
    ) -> None:
        url = httpx.URL(base_url)
        if url.scheme not in ("http", "https") or not url.host:
            raise ValueError(f"base_url must look like http://host:port, got {base_url!r}")
        self.base_url = str(url).rstrip("/")
        self.retry = retry
        self.timeout = timeout if isinstance(timeout, httpx.Timeout) else httpx.Timeout(timeout)
        self.headers = {"Accept": "application/json", "User-Agent": "planar-pose-client"}
        if api_key:
            self.headers["Authorization"] = f"Bearer {api_key}"

    def http_options(self) -> dict[str, Any]:
        """Keyword arguments for httpx.Client / httpx.AsyncClient."""
        return {"base_url": self.base_url, "timeout": self.timeout, "headers": self.headers}

    @staticmethod
    def predict_request(
        images: Iterable[ImageInput],
        mode: Mode,
        model: str | None = None,
        fx: float | None = None,
        camera: str | None = None,
        regions: str | None = None,
        same_camera: bool = False,
    ) -> dict[str, Any]:
        """Keyword arguments of `request()` for POST /v1/predict (or, with `model`,
        /v1/models/{model}/predict): every image as one multipart field `image`, in order,
        and the query: the camera's focal length `fx` (px of the images) or a stored `camera`
        id, the `regions` grid, `same_camera` (one joint fx for all the images). Reads and
        encodes all images first, so a bad one fails here."""
        check_model(model)
        params: dict[str, Any] = {"mode": mode}
        if fx is not None:
            params["fx"] = check_positive(fx, "fx")
        if camera is not None:
            if fx is not None:
                raise ValueError("give fx or camera, not both (the camera has its own fx)")
            params["camera"] = check_camera_id(camera)
        if regions is not None:
            if not REGIONS.fullmatch(regions):
                raise ValueError(
                    f"regions must be AxE or AxExD1,D2,... (e.g. 8x3 or 8x3x60,120), "
                    f"got {regions!r}"
                )
            params["regions"] = regions
        if same_camera:
            params["same_camera"] = "true"
        if is_single_image(images):
            raise TypeError("predict_many takes a list of images; use predict for one image")
        uploads = [to_upload(image, i) for i, image in enumerate(images)]
        if not uploads:
            raise ValueError("predict_many needs at least one image")
        return {
            "method": "POST",
            "url": "/v1/predict" if model is None else f"/v1/models/{model}/predict",
            "params": params,
            "files": [("image", tuple(upload)) for upload in uploads],
        }

    @staticmethod
    def create_camera_request(
        fx: float,
        fy: float | None = None,
        cx: float | None = None,
        cy: float | None = None,
        dist: Sequence[float] | None = None,
        width: int | None = None,
        height: int | None = None,
        name: str | None = None,
    ) -> dict[str, Any]:
        """Keyword arguments of `request()` for POST /v1/cameras with the intrinsics as JSON
        (fields left None are not sent)."""
        body: dict[str, Any] = {"fx": check_positive(fx, "fx")}
        if fy is not None:
            body["fy"] = check_positive(fy, "fy")
        for key, value in (("cx", cx), ("cy", cy)):
            if value is not None:
                body[key] = check_finite(value, key)
        if dist is not None:
            if isinstance(dist, (str, bytes)) or not dist:
                raise ValueError("dist must be a non-empty list of numbers [k1, k2, p1, p2, k3]")
            body["dist"] = [check_finite(k, "dist") for k in dist]
        for key, size in (("width", width), ("height", height)):
            if size is not None:
                if isinstance(size, bool) or not isinstance(size, numbers.Integral) or size <= 0:
                    raise ValueError(f"{key} must be a whole number of pixels > 0, got {size!r}")
                body[key] = int(size)
        if name is not None:
            body["name"] = name
        try:  # the service's rules (types and bounds of real cameras)
            CameraIntrinsics.model_validate(body)
        except ValidationError as exc:
            problems = "; ".join(
                f"{'.'.join(str(p) for p in e['loc']) or 'camera'}: {e['msg']}"
                for e in exc.errors()
            )
            raise ValueError(f"not a camera the service takes: {problems}") from None
        return {"method": "POST", "url": "/v1/cameras", "json": body}

    @staticmethod
    def learn_camera_request(
        photos: Iterable[ImageInput], model: str | None = None, name: str | None = None
    ) -> dict[str, Any]:
        """Keyword arguments of `request()` for POST /v1/cameras with photos of the object
        taken by the camera (multipart, field `image` repeated), `model` the corner model
        that finds the object in them."""
        check_model(model)
        if is_single_image(photos):
            raise TypeError("learn_camera takes a list of photos (3 or more, all of one size)")
        uploads = [to_upload(photo, i) for i, photo in enumerate(photos)]
        if not uploads:
            raise ValueError("learn_camera needs photos (3 or more, all of one size)")
        params = {k: v for k, v in (("model", model), ("name", name)) if v is not None}
        return {
            "method": "POST",
            "url": "/v1/cameras",
            "params": params,
            "files": [("image", tuple(upload)) for upload in uploads],
        }

    @staticmethod
    def camera_url(camera_id: str) -> str:
        """/v1/cameras/{id}, the id checked first."""
        return f"/v1/cameras/{check_camera_id(camera_id)}"

    def after_attempt(
        self,
        retry: int,
        response: httpx.Response | None,
        error: httpx.TransportError | None,
        retries: int | None = None,
        idempotent: bool = True,
    ) -> httpx.Response | float:
        """Judge attempt number `retry` (0 = the first): the successful response to return,
        or the seconds to wait before trying again. Raises the mapped PoseError when the
        attempt failed for good. `retries` overrides the policy's count (0 for probes). A call
        that changes something (`idempotent` False) is tried again after a transport error
        only when the request never left (connection refused), so it cannot happen twice."""
        left = (self.retry.retries if retries is None else retries) - retry
        if response is None and not idempotent and not isinstance(error, _NOT_SENT):
            left = 0
        if response is None:
            if left > 0:
                return self.retry.delay(retry)
            attempts = retry + 1
            raise PoseConnectionError(
                f"cannot reach {self.base_url}: {_describe(error)} "
                f"({attempts} attempt{'s' if attempts > 1 else ''})",
                attempts=attempts,
            ) from error
        if response.is_success:
            return response
        if response.status_code in self.retry.statuses and left > 0:
            return self.retry.delay(retry, _retry_after(response))
        raise error_from_response(response)

    @staticmethod
    def parse_predictions(response: httpx.Response, expected: int) -> list[Prediction]:
        """The results of POST /v1/predict, checked to hold one per image sent."""
        answer = _parse(PredictResponse, response)
        if len(answer.results) != expected:
            raise PoseError(
                f"sent {expected} image(s) but got {len(answer.results)} result(s)",
                status=response.status_code,
                code="invalid_response",
            )
        return answer.results

    @staticmethod
    def parse_model_card(response: httpx.Response) -> ModelCard:
        return _parse(ModelCard, response)

    @staticmethod
    def parse_model_list(response: httpx.Response) -> ModelList:
        return _parse(ModelList, response)

    @staticmethod
    def parse_camera(response: httpx.Response) -> Camera:
        return _parse(Camera, response)

    @staticmethod
    def parse_camera_list(response: httpx.Response) -> list[Camera]:
        return _parse(CameraList, response).cameras


def check_model(model: str | None) -> None:
    """ValueError unless `model` is None or a name the service accepts in a URL."""
    if model is not None and not MODEL_NAME.fullmatch(model):
        raise ValueError(f"not a model name: {model!r} (letters, digits, '.', '_', '-')")


def check_camera_id(camera_id: str) -> str:
    """`camera_id`, or ValueError when it cannot be a camera id."""
    if not isinstance(camera_id, str) or not CAMERA_ID.fullmatch(camera_id):
        raise ValueError(f"not a camera id: {camera_id!r} (e.g. 'c-3f2a9b1c'; see cameras())")
    return camera_id


def check_finite(value: float, name: str, what: str = "a finite number") -> float:
    """`value` as a float, or ValueError when it is not a finite number."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name} must be {what}, got {value!r}")
    number = float(value)
    if not math.isfinite(number):
        raise ValueError(f"{name} must be {what}, got {value!r}")
    return number


def check_positive(value: float, name: str) -> float:
    """`value` as a float, or ValueError when it is not a positive number of pixels."""
    what = "a positive number of pixels"
    number = check_finite(value, name, what)
    if number <= 0:
        raise ValueError(f"{name} must be {what}, got {value!r}")
    return number


def _parse(model: type[M], response: httpx.Response) -> M:
    try:
        return model.model_validate_json(response.content)
    except ValidationError as exc:
        raise PoseError(
            f"unexpected answer from {response.request.url.path}: "
            f"{exc.error_count()} problem(s), first: {_first_problem(exc)}",
            status=response.status_code,
            code="invalid_response",
        ) from exc


def _first_problem(exc: ValidationError) -> str:
    first = exc.errors()[0]
    where = ".".join(str(part) for part in first["loc"]) or "body"
    return f"{where}: {first['msg']}"


def _retry_after(response: httpx.Response) -> float | None:
    """A `Retry-After` header given in seconds (the HTTP-date form is ignored)."""
    try:
        return max(0.0, float(response.headers["Retry-After"]))
    except (KeyError, ValueError):
        return None


def _describe(error: BaseException | None) -> str:
    if isinstance(error, httpx.TimeoutException):
        return f"timed out ({type(error).__name__})"
    if isinstance(error, httpx.ConnectError):
        return f"connection failed ({error})" if str(error) else "connection failed"
    return f"{type(error).__name__}: {error}" if error is not None else "no answer"
