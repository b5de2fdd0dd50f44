"""The ONNX pose network in onnxruntime, with its model card.

The graph's inputs, outputs and defaults are `service.core.onnx_contract`'s; the card is the
JSON in metadata_props `model_card` (or the `<name>.json` beside the file).
"""

from __future__ import annotations

import base64
import binascii
import json
import os
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import onnxruntime as ort

from service.core.onnx_contract import (
    CARD_KEY,
    CORNERS,
    FOCAL,
    PATTERN,
    PIXEL_ASPECT,
    PROBABILITIES,
    TEXTURE_KEY,
    UNDISTORTED,
    VIEW,
)
from service.core.pose import FOCAL_PRIOR, is_focal_prior
from service.core.refine import Texture
from service.core.regions import NUM_CLASSES, Z_SPLIT_CM
from service.pipeline.onnx_file import OnnxFileError, read_metadata
from service.pipeline.results import Training

#: Runs of more inputs than this give the memory onnxruntime's arena took for them back
#: when they end (a batch of 16 images grows it by ~70 MB, of 144 by ~640 MB, held for good
#: otherwise); smaller runs, the common case, keep the arena warm.
SHRINK_ABOVE = 2
_SHRINK = ort.RunOptions()
_SHRINK.add_run_config_entry("memory.enable_memory_arena_shrinkage", "cpu:0")


@dataclass(frozen=True)
class Answer:
    """A graph's outputs for N inputs: probabilities float64 [N, 9] (rows summing to 1),
    corners float64 [N, 4, 2] in frame pixels, the pattern's P(present) float64 [N] and the
    corners without the lens's distortion float64 [N, 4, 2] (each None: no such output)."""

    probabilities: np.ndarray
    corners: np.ndarray | None
    pattern: np.ndarray | None
    undistorted: np.ndarray | None = None


class ModelLoadError(RuntimeError):
    """The model file is missing, not ONNX, or does not follow the I/O contract."""


def read_card(path: Path) -> dict[str, Any]:
    """The card of the ONNX file `path` without loading its graph: the `model_card` of its
    metadata (`service.pipeline.onnx_file`), else the `<name>.json` next to it; ModelLoadError when
    the file is not ONNX, is missing or has no card."""
    try:
        text = read_metadata(path).get(CARD_KEY)
    except OnnxFileError as exc:
        raise ModelLoadError(f"{path}: not a loadable ONNX model ({exc})") from None
    except OSError:
        raise ModelLoadError(f"model file not found: {path}") from None
    if text is None:
        sidecar = path.with_suffix(".json")
        if not sidecar.is_file():
            raise ModelLoadError(f"{path}: no {CARD_KEY} metadata and no {sidecar.name}")
        text = sidecar.read_text(encoding="utf-8")
    try:
        card = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ModelLoadError(f"{path}: model card is not JSON ({exc})") from None
    if not isinstance(card, dict) or "name" not in card:
        raise ModelLoadError(f"{path}: model card has no name")
    return card


def training_of(card: dict[str, Any]) -> Training:
    """How a model came to know its object, from its card: `zero-shot` (the generic corner
    network with the object's picture, not trained on it: the card's `zero_shot`),
    `fine-tuned` (trained from that network: architecture `corners-any`) or `trained`."""
    if "zero_shot" in card:
        return "zero-shot"
    if str(card.get("architecture", "")).startswith("corners-any"):
        return "fine-tuned"
    return "trained"


def read_texture_png(path: Path) -> tuple[bytes, np.ndarray] | None:
    """The object's front-on picture in the ONNX file's metadata (`TEXTURE_KEY`: a base64
    PNG, read without loading the graph) -> (the PNG's bytes, RGB uint8 [h, w, 3]), or None
    where the model carries none; ModelLoadError where it is not a readable image."""
    try:
        text = read_metadata(path).get(TEXTURE_KEY)
    except (OnnxFileError, OSError) as exc:
        raise ModelLoadError(f"{path}: not a loadable ONNX model ({exc})") from None
    if text is None:
        return None
    try:
        png = base64.b64decode(text, validate=True)
        data = np.frombuffer(png, np.uint8)
        rgb = cv2.imdecode(data, cv2.IMREAD_COLOR_RGB) if data.size else None
    except (binascii.Error, cv2.error):
        rgb = None
    if rgb is None or min(rgb.shape[:2]) < 8 or not png.startswith(b"\x89PNG"):
        raise ModelLoadError(f"{path}: metadata {TEXTURE_KEY!r} is not a PNG of the texture")
    return png, rgb


def _read_texture(path: Path) -> Texture | None:
    """The object's texture for the refinement (`read_texture_png`), or None."""
    found = read_texture_png(path)
    return None if found is None else Texture.of_rgb(found[1])


_SHARED_ALLOCATOR = threading.Lock()
_shared_allocator_registered = False


def _share_allocator() -> None:
    """Register one CPU arena for every session of this process (once): each session would
    otherwise keep an arena of its own, sized by its largest run (~8 MB for a corner model
    after a zoom pass; `benchmarks/bench_models.py`)."""
    global _shared_allocator_registered
    with _SHARED_ALLOCATOR:
        if not _shared_allocator_registered:
            memory = ort.OrtMemoryInfo(
                "Cpu", ort.OrtAllocatorType.ORT_ARENA_ALLOCATOR, 0, ort.OrtMemType.DEFAULT
            )
            ort.create_and_register_allocator(memory, None)
            _shared_allocator_registered = True


def session_options(intra_op_threads: int = 1, inter_op_threads: int = 1) -> ort.SessionOptions:
    """The options of every session: the threads, no spinning, errors-only logs, and the
    process's shared CPU arena."""
    _share_allocator()
    options = ort.SessionOptions()
    options.intra_op_num_threads = intra_op_threads
    options.inter_op_num_threads = inter_op_threads
    # Idle worker threads sleep instead of spinning: the CPU is shared with the web server.
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    options.add_session_config_entry("session.use_env_allocators", "1")
    # errors only: onnxruntime warns at load about every overridable initializer, and
    # `pixel_aspect` is one on purpose
    options.log_severity_level = 3
    return options


def open_session(
    source: Path | bytes,
    options: ort.SessionOptions,
    optimized: Path | None,
    path: Path,
    optimize: bool = True,
) -> ort.InferenceSession:
    """A session of `source` (a file or ONNX bytes); with `optimized` (a file path): the
    graph as onnxruntime optimized it, in its ORT format, read from there when the file
    exists (4-5x faster than optimizing the ONNX graph again: 0.25 s of CPU against 1.2 s
    for the book's corner graph, `benchmarks/bench_models.py`), else written there by this
    load (atomically; a cached file that does not load is removed and the ONNX file loaded
    instead). `optimize=False` and no such file: the graph as it is, nothing written (the
    book's corner graph: 0.4 s of CPU to load against 1.8 s, about 1.3x slower to run).
    ModelLoadError naming `path` when onnxruntime refuses the graph."""
    if optimized is not None and optimized.is_file():
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
        try:
            return ort.InferenceSession(str(optimized), options, providers=["CPUExecutionProvider"])
        except Exception:  # noqa: BLE001  # a stale or damaged cache: the ONNX file then
            optimized.unlink(missing_ok=True)
            options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    if not optimize:
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
        optimized = None
    part = None
    if optimized is not None:
        part = optimized.with_name(f".{optimized.name}.{os.getpid()}.{threading.get_ident()}")
        options.optimized_model_filepath = str(part)
        options.add_session_config_entry("session.save_model_format", "ORT")
    try:
        session = ort.InferenceSession(
            source if isinstance(source, bytes) else str(source),
            options,
            providers=["CPUExecutionProvider"],
        )
    except Exception as exc:  # onnxruntime raises its own Fail/InvalidGraph/... types
        if part is not None:
            part.unlink(missing_ok=True)
        raise ModelLoadError(f"{path}: not a loadable ONNX model ({exc})") from None
    if part is not None and optimized is not None:
        try:
            part.replace(optimized)
        except OSError:  # a cache that cannot be written: next time from the ONNX file again
            part.unlink(missing_ok=True)
    return session


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
    pattern_name: str | None = None  # the optional pattern output
    takes_view: bool = False  # whether the graph has the `view` input
    takes_focal: bool = False  # whether the graph has the `focal` input
    undistorted_name: str | None = None  # the optional undistorted corners output
    texture: Texture | None = None  # the object's texture (metadata), for the refinement

    @property
    def zooms(self) -> bool:
        """Whether the graph serves the zoom pass (`service.pipeline.zoom`): view in, pattern
        out."""
        return self.takes_view and self.pattern_name is not None and self.corners_name is not None

    @property
    def name(self) -> str:
        return str(self.card["name"])

    @property
    def training(self) -> Training:
        """How the model came to know its object (`training_of` its card)."""
        return training_of(self.card)

    @property
    def object_size_cm(self) -> tuple[float, float] | None:
        """The object's (width, height) cm from the card's profile (None: not stated)."""
        profile = self.card.get("profile")
        if not isinstance(profile, dict):
            return None
        try:
            size = (float(profile["width_cm"]), float(profile["height_cm"]))
        except (KeyError, TypeError, ValueError):
            return None
        return size if all(0 < v < 1e4 for v in size) else None

    @property
    def z_split_cm(self) -> float:
        """The near / far split of the card's profile, cm (the SPEC's where not stated)."""
        profile = self.card.get("profile")
        value = profile.get("z_split_cm") if isinstance(profile, dict) else None
        if isinstance(value, int | float) and not isinstance(value, bool) and 0 < value < 1e4:
            return float(value)
        return Z_SPLIT_CM

    @property
    def focal_prior(self) -> float:
        """The focal-length prior of the graph's camera model (x the SPEC camera's: the card's
        `camera_model.focal_prior_x_spec`, the object profile's) within `FOCAL_BOUNDS`; the
        project's `FOCAL_PRIOR` where the card does not state one."""
        camera = self.card.get("camera_model")
        value = camera.get("focal_prior_x_spec") if isinstance(camera, dict) else None
        return float(value) if is_focal_prior(value) else FOCAL_PRIOR

    @classmethod
    def load(
        cls,
        path: Path,
        intra_op_threads: int = 1,
        inter_op_threads: int = 1,
        graph: tuple[bytes, dict[str, Any]] | None = None,
        card: dict[str, Any] | None = None,
        optimized: Path | None = None,
        optimize: bool = True,
    ) -> PoseModel:
        """Open `path`, check the I/O contract, read the input size from the input shape.
        `graph` = (ONNX bytes, card): that graph instead of the file, `path` only naming it
        (`train/network/export.py` measures a graph before it writes it); `card`: the file's
        card as already read (`read_card`), else it is read here; `optimized`: the file of
        the optimized graph and `optimize` (`open_session`)."""
        if graph is None and not path.is_file():
            raise ModelLoadError(f"model file not found: {path}")
        options = session_options(intra_op_threads, inter_op_threads)
        session = open_session(
            path if graph is None else graph[0], options, optimized, path, optimize
        )
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
        pattern_out = by_name.get(PATTERN) if corners_out is not None else None
        flat_out = by_name.get(UNDISTORTED) if pattern_out is not None else None
        optional = [o for o in (corners_out, pattern_out, flat_out) if o is not None]
        if (
            probs_out is None
            or len(outputs) > 1 + len(optional)
            or probs_out.shape[-1] != NUM_CLASSES
        ):
            raise ModelLoadError(
                f"{path}: expected one output [N, {NUM_CLASSES}], or {PROBABILITIES!r} "
                f"[N, {NUM_CLASSES}] and {CORNERS!r} [N, 4, 2] (and {PATTERN!r} [N], "
                f"{UNDISTORTED!r} [N, 4, 2]); "
                f"got {sorted(by_name)}"
            )
        if corners_out is not None and list(corners_out.shape[1:]) != [4, 2]:
            raise ModelLoadError(f"{path}: output {CORNERS!r} must be [N, 4, 2]")
        if pattern_out is not None and len(pattern_out.shape) != 1:
            raise ModelLoadError(f"{path}: output {PATTERN!r} must be [N]")
        if flat_out is not None and list(flat_out.shape[1:]) != [4, 2]:
            raise ModelLoadError(f"{path}: output {UNDISTORTED!r} must be [N, 4, 2]")
        size = (int(shape[3]), int(shape[2]))
        if graph is not None:
            card = graph[1]
        elif card is None:
            card = read_card(path)
        if "input" in card and tuple(card["input"]) != size:
            raise ModelLoadError(f"{path}: card says input {card['input']}, graph says {size}")
        defaults = {i.name for i in session.get_overridable_initializers()}
        return cls(
            session,
            inputs[0].name,
            size,
            card,
            path,
            probs_out.name,
            None if corners_out is None else corners_out.name,
            PIXEL_ASPECT in defaults,
            None if pattern_out is None else pattern_out.name,
            VIEW in defaults,
            FOCAL in defaults,
            None if flat_out is None else flat_out.name,
            _read_texture(path) if corners_out is not None and graph is None else None,
        )

    def _feeds(
        self,
        batch: np.ndarray,
        pixel_aspect: np.ndarray | None,
        view: np.ndarray | None = None,
        focal: np.ndarray | None = None,
    ) -> dict[str, Any]:
        feeds: dict[str, Any] = {self.input_name: batch}
        if pixel_aspect is not None and self.takes_aspect:
            aspect = np.asarray(pixel_aspect, dtype=np.float32).reshape(-1)
            if aspect.shape != (len(batch),):
                raise ValueError(f"pixel_aspect: {aspect.size} values for {len(batch)} images")
            feeds[PIXEL_ASPECT] = aspect
        if view is not None and self.takes_view:
            views = np.asarray(view, dtype=np.float32)
            if views.shape != (len(batch), 3):
                raise ValueError(f"view: shape {views.shape} for {len(batch)} images, not [N, 3]")
            feeds[VIEW] = views
        if focal is not None:
            if not self.takes_focal:
                raise ValueError(f"model {self.name} does not take a focal length")
            fx = np.asarray(focal, dtype=np.float32).reshape(-1)
            if fx.shape != (len(batch),):
                raise ValueError(f"focal: {fx.size} values for {len(batch)} images")
            feeds[FOCAL] = fx
        return feeds

    def predict(self, batch: np.ndarray, pixel_aspect: np.ndarray | None = None) -> np.ndarray:
        """float32 [N, 3, H, W] in [0, 1] (and the pixel aspect [N] of each image, used by
        models that take it; None: 1) -> probabilities float64 [N, 9], rows summing to 1."""
        options = _SHRINK if len(batch) > SHRINK_ABOVE else None
        (raw,) = self.session.run([self.output_name], self._feeds(batch, pixel_aspect), options)
        return _normalised(raw)

    def run(
        self,
        batch: np.ndarray,
        pixel_aspect: np.ndarray | None = None,
        view: np.ndarray | None = None,
        focal: np.ndarray | None = None,
    ) -> Answer:
        """float32 [N, 3, H, W] in [0, 1], the pixel aspect [N] and the view [N, 3] (where
        each input lies in its camera's frame; models that take them; None: 1 and the whole
        frame) and the camera's focal length [N] (frame px of the input's width, 0: unknown;
        None: unknown for all; ValueError for a model without that input) -> every output
        the graph has (`Answer`)."""
        names = [self.output_name, self.corners_name, self.pattern_name, self.undistorted_name]
        wanted = [n for n in names if n is not None]
        feeds = self._feeds(batch, pixel_aspect, view, focal)
        options = _SHRINK if len(batch) > SHRINK_ABOVE else None
        out = dict(zip(wanted, self.session.run(wanted, feeds, options), strict=True))
        corners, pattern, flat = (
            None if n is None else np.asarray(out[n], dtype=np.float64) for n in names[1:]
        )
        return Answer(_normalised(out[self.output_name]), corners, pattern, flat)


def _normalised(raw: Any) -> np.ndarray:
    probs: np.ndarray = np.asarray(raw, dtype=np.float64)
    normalised: np.ndarray = probs / probs.sum(axis=1, keepdims=True)
    return normalised
