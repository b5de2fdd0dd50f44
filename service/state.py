"""What the routes share, kept on `app.state.pose`: settings, metrics, the inference limiter
and the predictor once the model has loaded (or why it has not)."""

from __future__ import annotations

import logging

import anyio

from service.metrics import Metrics
from service.model import ModelLoadError, PoseModel
from service.predictor import Predictor
from service.settings import Settings

log = logging.getLogger("uvicorn.error.pose")  # printed by uvicorn's handlers


class ServiceState:
    """The state of one app (one per worker process)."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.metrics = Metrics()
        # CPU-bound jobs beyond one per core only thrash caches and lengthen the tail: queue them.
        self.jobs = anyio.CapacityLimiter(settings.workers)
        self.predictor: Predictor | None = None
        self.problem = "model is loading"

    def load(self) -> None:
        """Load the model (blocking; run in a thread at startup). Failures go to `problem`."""
        settings = self.settings
        path = settings.resolved_model_path
        try:
            model = PoseModel.load(path, settings.intra_op_threads, settings.inter_op_threads)
        except ModelLoadError as exc:
            self.problem = f"model not loaded: {exc}"
            log.error("%s", self.problem)
            return
        self.predictor = Predictor(model, settings)
        log.info("model %s loaded from %s, input %s", model.name, path, model.input_size)
