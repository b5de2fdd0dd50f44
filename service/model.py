"""The ONNX pose network in onnxruntime, with its model card.

Contract (written by `train/export.py`): input `image` float32 [N, 3, H, W], RGB in [0, 1];
output `probabilities` float32 [N, 9] (softmax); metadata_props `model_card` = card JSON.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort

from service.regions import NUM_CLASSES


class ModelLoadError(RuntimeError):
    """The model file is missing, not ONNX, or does not follow the I/O contract."""


def _read_card(session: ort.InferenceSession, path: Path) -> dict[str, Any]:
    """The card from the ONNX metadata, else from the `<name>.json` next to the model."""
    text = session.get_modelmeta().custom_metadata_map.get("model_card")
    if text is None:
        sidecar = path.with_suffix(".json")
        if not sidecar.is_file():
            raise ModelLoadError(f"{path}: no model_card metadata and no {sidecar.name}")
        text = sidecar.read_text(encoding="utf-8")
    try:
        card = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ModelLoadError(f"{path}: model card is not JSON ({exc})") from None
    if not isinstance(card, dict) or "name" not in card:
        raise ModelLoadError(f"{path}: model card has no name")
    return card


@dataclass(frozen=True)
class PoseModel:
    """One onnxruntime session (thread-safe, shared by all requests) and its card."""

    session: ort.InferenceSession
    input_name: str
    input_size: tuple[int, int]  # (W, H) pixels
    card: dict[str, Any]
    path: Path

    @property
    def name(self) -> str:
        return str(self.card["name"])

    @classmethod
    def load(cls, path: Path, intra_op_threads: int = 1, inter_op_threads: int = 1) -> PoseModel:
        """Open `path`, check the I/O contract, read the input size from the input shape."""
        if not path.is_file():
            raise ModelLoadError(f"model file not found: {path}")
        options = ort.SessionOptions()
        options.intra_op_num_threads = intra_op_threads
        options.inter_op_num_threads = inter_op_threads
        # Idle worker threads sleep instead of spinning: the CPU is shared with the web server.
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")
        try:
            session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own Fail/InvalidGraph/... types
            raise ModelLoadError(f"{path}: not a loadable ONNX model ({exc})") from None
        inputs, outputs = session.get_inputs(), session.get_outputs()
        shape = inputs[0].shape if len(inputs) == 1 else None
        if (
            shape is None
            or len(shape) != 4
            or shape[1] != 3
            or not all(isinstance(d, int) and d > 0 for d in shape[2:])
        ):
            raise ModelLoadError(f"{path}: expected one input [N, 3, H, W], got {shape}")
        if len(outputs) != 1 or outputs[0].shape[-1] != NUM_CLASSES:
            raise ModelLoadError(f"{path}: expected one output [N, {NUM_CLASSES}]")
        size = (int(shape[3]), int(shape[2]))
        card = _read_card(session, path)
        if "input" in card and tuple(card["input"]) != size:
            raise ModelLoadError(f"{path}: card says input {card['input']}, graph says {size}")
        return cls(session, inputs[0].name, size, card, path)

    def predict(self, batch: np.ndarray) -> np.ndarray:
        """float32 [N, 3, H, W] in [0, 1] -> probabilities float64 [N, 9], rows summing to 1."""
        (raw,) = self.session.run(None, {self.input_name: batch})
        probs: np.ndarray = np.asarray(raw, dtype=np.float64)
        normalised: np.ndarray = probs / probs.sum(axis=1, keepdims=True)
        return normalised
