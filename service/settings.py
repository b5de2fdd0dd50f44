"""Service settings from the environment (prefix `POSE_`), e.g. `POSE_API_KEY=...`.

Lists accept JSON (`["a", "b"]`) or comma-separated values (`a,b`).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Annotated, Any

from pydantic import Field, SecretStr, field_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

from service.core.cells import RegionGrid
from service.core.paths import DEFAULT_MODEL_DIR, DEFAULT_MODEL_NAME


def _split_list(value: Any) -> Any:
    if isinstance(value, str):
        text = value.strip()
        if text.startswith("["):
            return json.loads(text)
        return [item.strip() for item in text.split(",") if item.strip()]
    return value


class Settings(BaseSettings):
    """Every knob of the service; defaults serve the shipped model on 127.0.0.1:8000."""

    model_config = SettingsConfigDict(env_prefix="POSE_", protected_namespaces=())

    model_dir: Path | None = Field(
        default=None,
        description="Model folder: every <name>.onnx (with its card) is served; default models/.",
    )
    default_model: str = Field(
        default=DEFAULT_MODEL_NAME,
        description="The folder's model that /v1/predict answers with (also as "
        "/v1/models/default/...).",
    )
    model_path: Path | None = Field(
        default=None,
        description="Serve this ONNX file as the default model instead of the folder's "
        "(with POSE_MODEL_DIR also set: the folder's other models too).",
    )
    model_watch_s: float = Field(
        default=0.0, ge=0, description="Poll the model folder every this many s, 0 = only reload."
    )
    model_grace_s: float = Field(
        default=60.0,
        ge=0,
        description="A served model whose file disappears keeps answering this many s, "
        "until a loadable file of its name is back (an rm + cp deploy); then it is dropped.",
    )
    model_memory_mb: float = Field(
        default=384.0,
        gt=0,
        description="Memory the loaded models of one worker may take (MB, each estimated "
        "from its graph: ~21 for a corner model); beyond it the least recently used are "
        "unloaded (never the default model). Every model of the folder is listed at start; "
        "the others load on first use.",
    )
    model_prepare: bool = Field(
        default=True,
        description="Write the optimized graph of every model in the background (lowest "
        "priority, one worker): a model's first load then takes 0.1-0.3 s of CPU instead of "
        "0.3-0.4 s unoptimized, optimized after (service/pipeline/model_cache.py).",
    )
    optimized_dir: Path | None = Field(
        default=None,
        description="Where the optimized graphs are kept (named by their model's content and "
        "the onnxruntime version; servers may share it, and a persistent folder spares a "
        "restarted server optimizing its models again). Default: the runtime folder's "
        "`optimized`, or a temporary folder of the process.",
    )
    workers: int = Field(
        default=0, ge=0, description="Server processes (planar-pose-serve), 0 = one per CPU."
    )
    runtime_dir: Path | None = Field(
        default=None,
        description="Shared by the worker processes (readiness, reloads, metrics); set by "
        "planar-pose-serve, not by hand.",
    )
    host: str = "127.0.0.1"
    port: int = Field(default=8000, ge=1, le=65535)
    api_key: SecretStr | None = Field(
        default=None,
        description="When set, /v1/* needs `Authorization: Bearer <key>` or `X-API-Key`.",
    )
    max_upload_bytes: int = Field(default=20 * 1024 * 1024, gt=0, description="Body limit.")
    max_pixels: int = Field(default=50_000_000, gt=0, description="Per image, from its header.")
    max_request_pixels: int = Field(
        default=64_000_000,
        gt=0,
        description="Pixels decoded for one request (all its images; one stream frame), "
        "from the headers before any is decoded (a large JPEG counts at the reduced size "
        "libjpeg decodes it at); more: 413.",
    )
    max_images: int = Field(default=16, gt=0, description="Images per request.")
    intra_op_threads: int = Field(default=1, ge=0, description="onnxruntime threads, 0 = auto.")
    inter_op_threads: int = Field(default=1, ge=0)
    inference_workers: int = Field(
        default=0, ge=0, description="Images decoded/classified at once, 0 = one per CPU."
    )
    cors_origins: Annotated[list[str], NoDecode] = Field(default_factory=list)
    zoom: bool = Field(
        default=True,
        description="Whole mode: a second look at 2x tiles where the board is small or "
        "missed (service/pipeline/zoom.py; models with its view input).",
    )
    zoom_search: bool = Field(
        default=True,
        description="With ZOOM: also search the tiles of an image where no board was found "
        "(1 + ZOOM_SEARCH_TILES network inputs for each; off: at most 2 per image, a small "
        "board's tile). Zero-shot models search only photos with more pixels than the network "
        "reads: their presence threshold is measured on whole frames.",
    )
    zoom_search_tiles: int = Field(
        default=1,
        ge=1,
        le=9,
        description="Tiles searched where no board was found: those centred nearest the "
        "whole frame's corner guess (9: all; service/pipeline/zoom.py).",
    )
    refine: bool = Field(
        default=True,
        description="Whole mode, corner models that carry their object's texture: align the "
        "texture to the photo at its own resolution, started from the network's corners "
        "(service/core/refine.py); off: the network's corners as they are.",
    )
    refine_budget_ms: float = Field(
        default=1000.0,
        gt=0,
        le=10_000,
        description="Time one image's refinement may take, ms (a safety bound: it takes "
        "10-100 ms; the work itself is bounded by the crop's size and ECC's iterations): past "
        "it the alignment stops and the network's corners, or the last alignment that held, "
        "are kept.",
    )
    stream_track_every: int = Field(
        default=10,
        ge=0,
        le=10_000,
        description="Streams, whole mode, models that carry their texture: a frame after one "
        "whose object was found is refined from that frame's corners without the network "
        "(`tracked` in the answer); the network still looks at every this many frames, to "
        "catch drift, and the track stands where the network finds the object within 1 px "
        "of it. 0 or 1: the network answers every frame.",
    )
    exif_focal: bool = Field(
        default=True,
        description="Whole mode, models that take a focal length: where a request gives no "
        "fx, use the one of the photo's EXIF 35 mm equivalent focal length "
        "(service/pipeline/exif.py).",
    )
    camera_db: Path | None = Field(
        default=None,
        description="The SQLite file of the cameras the service learns (/v1/cameras), shared "
        "by the worker processes; default $XDG_STATE_HOME/planar-pose/cameras.sqlite3 "
        "(~/.local/state/...).",
    )
    max_cameras: int = Field(
        default=1000, ge=1, description="Cameras the store holds at most; more: 409."
    )
    regions: str | None = Field(
        default=None,
        description="The finer-regions grid every whole-mode answer names its pose's cell in "
        "(docs/pose.md, e.g. 8x3x60) where the request gives no regions=; unset: none.",
    )
    sliding_scales: Annotated[list[float], NoDecode] = Field(
        default_factory=lambda: [1.0, 0.8, 0.65],
        description="Window sizes as fractions of the largest input-aspect window in the image.",
    )
    sliding_resolution: float = Field(
        default=1.0,
        gt=0,
        description="Working copy scale: the largest window measures this many network inputs.",
    )
    sliding_stride: int = Field(
        default=20, ge=1, description="Window step in working-copy px of an 80x60 network."
    )
    sliding_nms_iou: float = Field(default=0.3, gt=0, le=1)
    sliding_max_windows: int = Field(default=256, ge=1, description="Stride grows beyond it.")
    proposals_max: int = Field(default=16, ge=1, description="Object proposals per image.")
    proposals_resolution: float = Field(
        default=4.0,
        gt=0,
        description="Proposals working copy scale, in network inputs (4: 320x240 for 80x60).",
    )
    drain_s: float = Field(
        default=0.0,
        ge=0,
        le=3600,
        description="After SIGTERM: /readyz 503 at once, requests still accepted and answered "
        "this many s (a load balancer's time to let go), then the listener closes "
        "(service/api/drain.py). 0: it closes at once.",
    )
    graceful_timeout_s: int = Field(
        default=20,
        ge=0,
        description="Then: time the requests in flight have to finish before they are cut.",
    )
    log_level: str = "info"
    access_log: bool = True

    @field_validator("cors_origins", "sliding_scales", mode="before")
    @classmethod
    def _lists(cls, value: Any) -> Any:
        return _split_list(value)

    @field_validator("sliding_scales")
    @classmethod
    def _scales(cls, value: list[float]) -> list[float]:
        if not value or any(not 0 < s <= 1 for s in value):
            raise ValueError("sliding scales must be a non-empty list of numbers in (0, 1]")
        return value

    @field_validator("regions")
    @classmethod
    def _grid(cls, value: str | None) -> str | None:
        if value:
            RegionGrid.parse(value)
        return value or None

    @field_validator("api_key", mode="before")
    @classmethod
    def _empty_key(cls, value: Any) -> Any:
        return None if value == "" else value

    @property
    def inference_jobs(self) -> int:
        """Concurrent inference jobs: `inference_workers` or the CPUs this process may use."""
        return self.inference_workers or cpu_count()

    @property
    def model_memory_bytes(self) -> int:
        return int(self.model_memory_mb * 2**20)

    @property
    def process_count(self) -> int:
        """Server processes: `workers` or one per CPU."""
        return self.workers or cpu_count()

    @property
    def resolved_camera_db(self) -> Path:
        """`camera_db`, or cameras.sqlite3 in the user's state folder."""
        if self.camera_db is not None:
            return self.camera_db
        state = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
        return Path(state) / "planar-pose" / "cameras.sqlite3"

    @property
    def resolved_model_dir(self) -> Path:
        return self.model_dir if self.model_dir is not None else DEFAULT_MODEL_DIR

    @property
    def resolved_model_path(self) -> Path:
        """The default model's ONNX file: `model_path` or `<model dir>/<default_model>.onnx`."""
        if self.model_path is not None:
            return self.model_path
        return self.resolved_model_dir / f"{self.default_model}.onnx"


def cpu_count() -> int:
    """The CPUs this process may run on."""
    return len(os.sched_getaffinity(0))
