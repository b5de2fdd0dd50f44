"""What the sync and async clients share: settings, request building, retry decisions and
response parsing. Only the act of sending (and sleeping between attempts) differs between them.
"""

from __future__ import annotations

import math
import random
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, TypeVar

import httpx
from pydantic import BaseModel, ValidationError

from .errors import PoseConnectionError, PoseError, error_from_response
from .images import ImageInput, is_single_image, to_upload
from .models import Mode, ModelCard, ModelList, Prediction, PredictResponse

DEFAULT_TIMEOUT_S = 30.0
#: What the service accepts as a model name in a URL.
MODEL_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")

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
        images: Iterable[ImageInput], mode: Mode, model: str | None = None, fx: float | None = None
    ) -> dict[str, Any]:
        """Keyword arguments of `request()` for POST /v1/predict (or, with `model`,
        /v1/models/{model}/predict): every image as one multipart field `image`, in order,
        and the camera's focal length `fx` (px of the images) if given. Reads and encodes all
        images first, so a bad one fails here."""
        if model is not None and not MODEL_NAME.fullmatch(model):
            raise ValueError(f"not a model name: {model!r} (letters, digits, '.', '_', '-')")
        if fx is not None and not (math.isfinite(fx) and fx > 0):
            raise ValueError(f"fx must be a positive number of pixels, got {fx}")
        if is_single_image(images):
            raise TypeError("predict_many takes a list of images; use predict for one image")
        uploads = [to_upload(image, i) for i, image in enumerate(images)]
        if not uploads:
            raise ValueError("predict_many needs at least one image")
        return {
            "method": "POST",
            "url": "/v1/predict" if model is None else f"/v1/models/{model}/predict",
            "params": {"mode": mode} if fx is None else {"mode": mode, "fx": fx},
            "files": [("image", tuple(upload)) for upload in uploads],
        }

    def after_attempt(
        self,
        retry: int,
        response: httpx.Response | None,
        error: httpx.TransportError | None,
        retries: int | None = None,
    ) -> httpx.Response | float:
        """Judge attempt number `retry` (0 = the first): the successful response to return,
        or the seconds to wait before trying again. Raises the mapped PoseError when the
        attempt failed for good. `retries` overrides the policy's count (0 for probes)."""
        left = (self.retry.retries if retries is None else retries) - retry
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
