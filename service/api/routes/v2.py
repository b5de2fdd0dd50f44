"""The Open Inference Protocol (KServe v2 REST) under /v2, for KServe/Triton/Seldon clients.

Errors here are the protocol's `{"error": "message"}` (service.api.errors picks the shape by path).
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version
from typing import Any

import anyio
import numpy as np
from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse

from service.api.deps import (
    AUTHORISED,
    LimiterDep,
    MetricsDep,
    NamedPredictorDep,
    SettingsDep,
    StateDep,
    served_name,
)
from service.api.errors import ApiError
from service.api.oip import InferRequest, ProtocolError, infer_response, parse_infer_request
from service.core.preprocess import ImageDecodeError, ImageTooLargeError
from service.core.regions import NUM_CLASSES
from service.pipeline.job import Job, Options, too_large_code
from service.pipeline.predictor import Predictor

health = APIRouter(tags=["v2"])
router = APIRouter(tags=["v2"], dependencies=AUTHORISED)

try:
    SERVER_VERSION = version("planar-pose")
except PackageNotFoundError:  # running from a source tree without installing
    SERVER_VERSION = "0"


def _model_version(predictor: Predictor) -> str:
    return str(predictor.model.card.get("version", "1"))


def _check_version(predictor: Predictor, name: str, wanted: str | None) -> None:
    if wanted is not None and wanted != _model_version(predictor):
        raise ApiError(
            404,
            "model_not_found",
            f"model {name!r} has version {_model_version(predictor)!r}, not {wanted!r}",
        )


@health.get("/v2/health/live")
async def live() -> dict[str, bool]:
    """The server is up."""
    return {"live": True}


@health.get("/v2/health/ready")
async def ready(state: StateDep) -> JSONResponse:
    """Every worker has its default model: 200 {"ready": true}, else 503 {"ready": false}."""
    ok = state.not_ready() is None
    return JSONResponse({"ready": ok}, status_code=200 if ok else 503)


@router.get("/v2")
async def server_metadata() -> dict[str, Any]:
    """Server name, version and protocol extensions."""
    return {"name": "planar-pose", "version": SERVER_VERSION, "extensions": ["binary_tensor_data"]}


@router.get("/v2/models/{name}")
@router.get("/v2/models/{name}/versions/{model_version}")
async def model_metadata(
    name: str, state: StateDep, predictor: NamedPredictorDep, model_version: str | None = None
) -> dict[str, Any]:
    """Inputs (FP32 network input or BYTES encoded images) and outputs of model `name` (its
    served name: `default` is the default model's)."""
    _check_version(predictor, name, model_version)
    w, h = predictor.model.input_size
    return {
        "name": served_name(state, predictor),
        "versions": [_model_version(predictor)],
        "platform": "onnxruntime_onnx",
        "inputs": [
            {"name": "image", "datatype": "FP32", "shape": [-1, 3, h, w]},
            {"name": "image_bytes", "datatype": "BYTES", "shape": [-1]},
        ],
        "outputs": [
            {"name": "probabilities", "datatype": "FP32", "shape": [-1, NUM_CLASSES]},
            {"name": "class_id", "datatype": "INT64", "shape": [-1]},
        ],
    }


@router.get("/v2/models/{name}/ready")
@router.get("/v2/models/{name}/versions/{model_version}/ready")
async def model_ready(
    name: str, state: StateDep, predictor: NamedPredictorDep, model_version: str | None = None
) -> dict[str, Any]:
    """Model `name` is loaded (unknown names: 404)."""
    _check_version(predictor, name, model_version)
    return {"name": served_name(state, predictor), "ready": True}


def _probabilities(predictor: Predictor, infer: InferRequest, job: Job | None) -> np.ndarray:
    """[N, 9] from the images of `job` (admitted from their headers) decoded as in whole mode,
    else from the tensor as is."""
    if job is not None:
        results = predictor.run(job).results
        return np.array([r.probabilities for r in results], dtype=np.float64)
    tensor = infer.tensor
    w, h = predictor.model.input_size
    if tensor is None or tensor.ndim != 4 or tensor.shape[1:] != (3, h, w):
        raise ProtocolError(
            400, f"input {infer.input_name!r}: shape must be [N, 3, {h}, {w}] for this model"
        )
    if not np.isfinite(tensor).all():
        raise ProtocolError(400, f"input {infer.input_name!r}: values must be finite")
    return predictor.model.predict(tensor)


@router.post("/v2/models/{name}/infer")
@router.post("/v2/models/{name}/versions/{model_version}/infer")
async def infer(
    name: str,
    request: Request,
    state: StateDep,
    predictor: NamedPredictorDep,
    settings: SettingsDep,
    limiter: LimiterDep,
    metrics: MetricsDep,
    model_version: str | None = None,
) -> dict[str, Any]:
    """Classify an FP32 [N, 3, H, W] tensor or BYTES [N] encoded images."""
    _check_version(predictor, name, model_version)
    header = request.headers.get("inference-header-content-length")
    if header is not None and not header.isdigit():
        raise ApiError(400, "bad_request", "Inference-Header-Content-Length must be an integer")
    body = await request.body()
    try:
        # a JSON body of megabytes takes a while: parsed in a thread, not on the event loop
        parsed = await anyio.to_thread.run_sync(
            parse_infer_request, body, int(header) if header else None
        )
        count = len(parsed.tensor) if parsed.tensor is not None else len(parsed.images or [])
        if not 0 < count <= settings.max_images:
            raise ProtocolError(400, f"batch of {count}: send 1 to {settings.max_images} items")
        job = None
        if parsed.images is not None:  # from the headers, before waiting for a job slot
            job = predictor.admit([(None, data) for data in parsed.images], Options())
        probs = await anyio.to_thread.run_sync(
            _probabilities, predictor, parsed, job, limiter=limiter
        )
    except ProtocolError as exc:
        raise ApiError(exc.status, "bad_request", exc.message) from None
    except ImageTooLargeError as exc:
        raise ApiError(413, too_large_code(exc), str(exc)) from None
    except ImageDecodeError as exc:
        raise ApiError(400, "undecodable_image", str(exc)) from None
    metrics.images.labels("v2").inc(count)
    return infer_response(served_name(state, predictor), _model_version(predictor), parsed, probs)
