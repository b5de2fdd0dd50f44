"""What the routes share, kept on `app.state.pose`: settings, metrics, the inference limiter,
the served models, and (under `planar-pose-serve --workers N`) the other workers."""

from __future__ import annotations

import asyncio
import logging
import time

import anyio

from service.api.drain import Drain
from service.cameras.store import CameraStore
from service.metrics import Metrics
from service.pipeline.predictor import Predictor
from service.pipeline.registry import ModelRegistry, ReloadReport
from service.settings import Settings
from service.workers import WorkerRuntime

log = logging.getLogger("uvicorn.error.pose")  # printed by uvicorn's handlers

#: Seconds between two looks at the other workers' reloads.
SYNC_INTERVAL_S = 0.5


class ServiceState:
    """The state of one app (one per worker process)."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.metrics = Metrics()
        # CPU-bound jobs beyond one per core only thrash caches and lengthen the tail: queue them.
        self.jobs = anyio.CapacityLimiter(settings.inference_jobs)
        self.models = ModelRegistry(settings, self.metrics)
        self.drain = Drain(settings.drain_s)
        self.cameras = CameraStore(settings.resolved_camera_db, settings.max_cameras, self.metrics)
        self.loaded = False
        self.runtime = (
            WorkerRuntime(settings.runtime_dir, settings.process_count)
            if settings.runtime_dir is not None
            else None
        )

    @property
    def predictor(self) -> Predictor | None:
        """The default model's predictor (what /v1/predict uses), None until loaded."""
        return self.models.default()

    async def predictor_of(self, name: str) -> Predictor:
        """The predictor of the served model `name`, its graph loaded first (in a worker
        thread) if it is not; UnknownModel, or ModelLoadError when the graph does not load."""
        found = self.models.loaded(name)
        if found is not None:
            return found
        return await anyio.to_thread.run_sync(self.models.get, name)

    @property
    def problem(self) -> str:
        """Why there is no default predictor."""
        if not self.loaded:
            return "model is loading"
        name = self.settings.default_model
        if name in self.models.problems:
            return f"model not loaded: {self.models.problems[name]}"
        served = ", ".join(self.models.names) or "none"
        folder = self.settings.resolved_model_dir
        return f"model not loaded: no {name}.onnx in {folder} (served: {served})"

    def not_ready(self) -> str | None:
        """None when requests can be answered by every worker, else why not (also while
        draining before a shutdown: the load balancer should send no more)."""
        draining = self.drain.problem()
        if draining is not None:
            return draining
        if self.predictor is None:
            return self.problem
        if self.runtime is not None:
            count = self.runtime.ready_count()
            if count < self.runtime.expected:
                return f"{count} of {self.runtime.expected} workers have loaded their models"
        return None

    def load(self) -> ReloadReport:
        """(Re)list this worker's models and load the default one (blocking: run it in a
        thread)."""
        report = self.models.reload()
        self.loaded = True
        if self.settings.model_prepare:
            self.models.prepare_in_background()
        if self.runtime is not None and self.predictor is not None:
            self.runtime.mark_ready()
        return report

    def reload_everywhere(self) -> ReloadReport:
        """Reload here now and make every other worker reload too."""
        report = self.load()
        if self.runtime is not None:
            self.runtime.bump()
        return report

    async def follow(self) -> None:
        """Background task: reload when another worker was asked to, or (POSE_MODEL_WATCH_S)
        when a model file changed or the grace of a vanished one ended. Runs until
        cancelled."""
        watch = self.settings.model_watch_s
        if self.runtime is None and watch == 0:
            return
        interval = watch if self.runtime is None else min(SYNC_INTERVAL_S, watch or SYNC_INTERVAL_S)
        last = await asyncio.to_thread(self.models.folder_signature)
        while True:
            await asyncio.sleep(interval)
            asked = self.runtime is not None and self.runtime.reload_asked()
            now = await asyncio.to_thread(self.models.folder_signature) if watch else last
            grace = self.models.grace_ends()
            expired = watch > 0 and grace is not None and time.monotonic() >= grace
            if asked or now != last or expired:
                await asyncio.to_thread(self.load)
                last = now

    def close(self) -> None:
        self.models.close()
        if self.runtime is not None:
            self.runtime.unmark()
