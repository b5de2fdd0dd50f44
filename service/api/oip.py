"""The Open Inference Protocol (KServe v2) codec: infer requests in, infer responses out.

JSON tensors (`data`: flat or nested, row-major; the JSON nested at most
`bounded_json.MAX_DEPTH` deep) and the binary tensor data extension that
tritonclient uses by default (JSON header of `Inference-Header-Content-Length` bytes, then the
raw tensors; BYTES elements as 4-byte little-endian length + bytes). In JSON, a BYTES element
is a string: here the base64 of one encoded image.
"""

from __future__ import annotations

import base64
import binascii
import math
import struct
from dataclasses import dataclass
from typing import Any

import numpy as np

from service import bounded_json
from service.bounded_json import JSONTooDeepError

#: FP32 tensors in the binary extension: little-endian float32.
FP32_LE = np.dtype("<f4")
OUTPUTS = ("probabilities", "class_id")


class ProtocolError(Exception):
    """A request the protocol refuses: answered `{"error": message}` with `status`."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status, self.message = status, message


@dataclass(frozen=True)
class InferRequest:
    """A parsed infer request with one input: a float32 tensor or a list of encoded images."""

    id: str | None
    input_name: str
    tensor: np.ndarray | None  # FP32 [N, 3, H, W]
    images: list[bytes] | None  # BYTES [N]
    outputs: list[str]


def _shape(value: Any, where: str) -> list[int]:
    if not isinstance(value, list) or not all(isinstance(d, int) and d >= 0 for d in value):
        raise ProtocolError(400, f"{where}: 'shape' must be a list of non-negative integers")
    return value


def _bytes_elements(raw: bytes, where: str) -> list[bytes]:
    """Binary BYTES tensor: each element as 4-byte little-endian length, then its bytes."""
    out, at = [], 0
    while at < len(raw):
        if at + 4 > len(raw):
            raise ProtocolError(400, f"{where}: truncated BYTES element length")
        (size,) = struct.unpack_from("<I", raw, at)
        if at + 4 + size > len(raw):
            raise ProtocolError(400, f"{where}: BYTES element longer than the data")
        out.append(raw[at + 4 : at + 4 + size])
        at += 4 + size
    return out


def _json_images(data: Any, where: str) -> list[bytes]:
    if not isinstance(data, list) or not all(isinstance(x, str) for x in data):
        raise ProtocolError(400, f"{where}: BYTES 'data' must be a list of base64 strings")
    try:
        return [base64.b64decode(x, validate=True) for x in data]
    except (binascii.Error, ValueError):
        raise ProtocolError(400, f"{where}: BYTES element is not valid base64") from None


def _tensor(spec: dict[str, Any], raw: bytes | None, where: str) -> np.ndarray:
    shape = _shape(spec.get("shape"), where)
    try:
        if raw is not None:
            if len(raw) % 4:
                raise ProtocolError(400, f"{where}: {len(raw)} bytes are not float32 values")
            flat = np.frombuffer(raw, dtype=FP32_LE)
        else:
            flat = np.asarray(spec.get("data"), dtype=np.float32).reshape(-1)
    except (TypeError, ValueError, OverflowError):
        raise ProtocolError(400, f"{where}: FP32 'data' must be numbers") from None
    if flat.size != math.prod(shape):
        raise ProtocolError(400, f"{where}: {flat.size} values for shape {shape}")
    tensor: np.ndarray = flat.reshape(shape).astype(np.float32, copy=False)
    return tensor


def parse_infer_request(body: bytes, header_length: int | None) -> InferRequest:
    """The request's JSON (and binary tensors after `header_length` bytes), checked."""
    if header_length is not None and header_length > len(body):
        raise ProtocolError(
            400,
            f"Inference-Header-Content-Length {header_length} is more than the body's "
            f"{len(body)} bytes",
        )
    head = body if header_length is None else body[:header_length]
    try:
        doc = bounded_json.loads(head)
    except JSONTooDeepError as exc:
        raise ProtocolError(400, f"request body is nested too deep: {exc}") from None
    except ValueError as exc:  # json.JSONDecodeError, UnicodeDecodeError
        raise ProtocolError(400, f"request body is not JSON: {exc}") from None
    inputs = doc.get("inputs") if isinstance(doc, dict) else None
    if not isinstance(inputs, list) or len(inputs) != 1 or not isinstance(inputs[0], dict):
        raise ProtocolError(400, "expected 'inputs' with exactly one tensor (FP32 or BYTES)")
    spec = inputs[0]
    name, datatype = spec.get("name"), spec.get("datatype")
    where = f"input {name!r}"
    if not isinstance(name, str) or datatype not in ("FP32", "BYTES"):
        raise ProtocolError(400, f"{where}: needs a 'name' and datatype FP32 or BYTES")
    parameters = spec.get("parameters") or {}
    if not isinstance(parameters, dict):
        raise ProtocolError(400, f"{where}: 'parameters' must be an object")
    size = parameters.get("binary_data_size")
    raw = None
    if size is not None:
        binary = body[len(head) :]
        if header_length is None or not isinstance(size, int) or size != len(binary):
            raise ProtocolError(400, f"{where}: binary_data_size does not match the body")
        raw = binary
    elif "data" not in spec:
        raise ProtocolError(400, f"{where}: no 'data'")
    images = None
    if datatype == "BYTES" and raw is not None:
        images = _bytes_elements(raw, where)
    elif datatype == "BYTES":
        images = _json_images(spec["data"], where)
    return InferRequest(
        id=str(doc["id"]) if "id" in doc else None,
        input_name=name,
        tensor=_tensor(spec, raw, where) if datatype == "FP32" else None,
        images=images,
        outputs=_requested_outputs(doc.get("outputs")),
    )


def _requested_outputs(value: Any) -> list[str]:
    if value is None:
        return list(OUTPUTS)
    names = (
        [o.get("name") if isinstance(o, dict) else None for o in value]
        if isinstance(value, list)
        else None
    )
    if not names or not all(isinstance(o, str) for o in names):
        raise ProtocolError(400, "'outputs' must be a list of {'name': ...}")
    unknown = [n for n in names if n not in OUTPUTS]
    if unknown:
        raise ProtocolError(400, f"unknown output {unknown[0]!r}; outputs: {', '.join(OUTPUTS)}")
    return [str(n) for n in names]


def infer_response(
    model: str, version: str, request: InferRequest, probabilities: np.ndarray
) -> dict[str, Any]:
    """The JSON infer response: `probabilities` FP32 [N, 9] and `class_id` INT64 [N]."""
    n = len(probabilities)
    tensors = {
        "probabilities": {
            "datatype": "FP32",
            "shape": [n, int(probabilities.shape[1])],
            "data": probabilities.astype(np.float32).reshape(-1).tolist(),
        },
        "class_id": {
            "datatype": "INT64",
            "shape": [n],
            "data": probabilities.argmax(axis=1).astype(np.int64).tolist(),
        },
    }
    answer: dict[str, Any] = {
        "model_name": model,
        "model_version": version,
        "outputs": [{"name": name, **tensors[name]} for name in request.outputs],
    }
    if request.id is not None:
        answer["id"] = request.id
    return answer
