"""The ONNX pose network in onnxruntime, with its model card.

Contract (written by `train/network/export.py`): input `image` float32 [N, 3, H, W], RGB in
[0, 1]; optionally `pixel_aspect` float32 [N], an input with a default of 1 (an overridable
initializer): the height over the width of an input pixel in the scene
(`service.preprocess.NetworkFrame.pixel_aspect`); output `probabilities` float32 [N, 9]
(softmax), optionally `corners` float32 [N, 4, 2] (the object's corners in input pixels,
order (-X,-Y), (+X,-Y), (+X,+Y), (-X,+Y)); metadata_props `model_card` = card JSON. A graph
with one output takes it as the probabilities whatever its name.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort

from service.regions import NUM_CLASSES

PROBABILITIES, CORNERS = "probabilities", "corners"  # output names (train/network/export.py)
PIXEL_ASPECT = "pixel_aspect"  # the optional input (an overridable initializer)


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
    output_name: str  # the probabilities
    corners_name: str | None = None  # the optional corners output
    takes_aspect: bool = False  # whether the graph has the `pixel_aspect` input

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
        # errors only: onnxruntime warns at load about every overridable initializer, and
        # `pixel_aspect` is one on purpose
        options.log_severity_level = 3
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
        by_name = {o.name: o for o in outputs}
        probs_out = outputs[0] if len(outputs) == 1 else by_name.get(PROBABILITIES)
        corners_out = by_name.get(CORNERS) if len(outputs) > 1 else None
        if (
            probs_out is None
            or len(outputs) > 1 + (corners_out is not None)
            or probs_out.shape[-1] != NUM_CLASSES
        ):
            raise ModelLoadError(
                f"{path}: expected one output [N, {NUM_CLASSES}], or {PROBABILITIES!r} "
                f"[N, {NUM_CLASSES}] and {CORNERS!r} [N, 4, 2]; got {sorted(by_name)}"
            )
        if corners_out is not None and list(corners_out.shape[1:]) != [4, 2]:
            raise ModelLoadError(f"{path}: output {CORNERS!r} must be [N, 4, 2]")
        size = (int(shape[3]), int(shape[2]))
        card = _read_card(session, path)
        if "input" in card and tuple(card["input"]) != size:
            raise ModelLoadError(f"{path}: card says input {card['input']}, graph says {size}")
        return cls(
            session,
            inputs[0].name,
            size,
            card,
            path,
            probs_out.name,
            None if corners_out is None else corners_out.name,
            any(i.name == PIXEL_ASPECT for i in session.get_overridable_initializers()),
        )

    def _feeds(self, batch: np.ndarray, pixel_aspect: np.ndarray | None) -> dict[str, Any]:
        feeds: dict[str, Any] = {self.input_name: batch}
        if pixel_aspect is not None and self.takes_aspect:
            aspect = np.asarray(pixel_aspect, dtype=np.float32).reshape(-1)
            if aspect.shape != (len(batch),):
                raise ValueError(f"pixel_aspect: {aspect.size} values for {len(batch)} images")
            feeds[PIXEL_ASPECT] = aspect
        return feeds

    def predict(self, batch: np.ndarray, pixel_aspect: np.ndarray | None = None) -> np.ndarray:
        """float32 [N, 3, H, W] in [0, 1] (and the pixel aspect [N] of each image, used by
        models that take it; None: 1) -> probabilities float64 [N, 9], rows summing to 1."""
        (raw,) = self.session.run([self.output_name], self._feeds(batch, pixel_aspect))
        return _normalised(raw)

    def predict_with_corners(
        self, batch: np.ndarray, pixel_aspect: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """As `predict`, and the corners float64 [N, 4, 2] in input pixels (None when the
        model has no corners output)."""
        if self.corners_name is None:
            return self.predict(batch, pixel_aspect), None
        raw, corners = self.session.run(
            [self.output_name, self.corners_name], self._feeds(batch, pixel_aspect)
        )
        return _normalised(raw), np.asarray(corners, dtype=np.float64)


def _normalised(raw: Any) -> np.ndarray:
    probs: np.ndarray = np.asarray(raw, dtype=np.float64)
    normalised: np.ndarray = probs / probs.sum(axis=1, keepdims=True)
    return normalised
