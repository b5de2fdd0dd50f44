"""Prometheus metrics: requests by route/status, latency, images processed, inference time
(counted by every room; the HTTP requests by `service.api.request_metrics`).

Under `planar-pose-serve --workers N` (PROMETHEUS_MULTIPROC_DIR set before the workers start)
every worker writes its values to files there and /metrics, answered by any worker, adds up
all of them (prometheus-client's multiprocess mode).
"""

from __future__ import annotations

import os

from prometheus_client import (
    CONTENT_TYPE_LATEST,
    CollectorRegistry,
    Counter,
    Histogram,
    ProcessCollector,
    generate_latest,
)
from prometheus_client.multiprocess import MultiProcessCollector

_LATENCY_BUCKETS = (0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 10.0)


class Metrics:
    """One registry per app (several apps can live in one process, e.g. in tests)."""

    content_type = CONTENT_TYPE_LATEST

    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        self.multiprocess_dir = os.environ.get("PROMETHEUS_MULTIPROC_DIR")
        if self.multiprocess_dir is None:
            ProcessCollector(registry=self.registry)  # per process: meaningless summed up
        self.requests = Counter(
            "pose_http_requests",
            "HTTP requests answered, by route template, method and status.",
            ["route", "method", "status"],
            registry=self.registry,
        )
        self.latency = Histogram(
            "pose_http_request_duration_seconds",
            "Time from request start to the last response byte, by route.",
            ["route"],
            buckets=_LATENCY_BUCKETS,
            registry=self.registry,
        )
        self.images = Counter(
            "pose_images_processed", "Images answered, by mode.", ["mode"], registry=self.registry
        )
        self.inference = Histogram(
            "pose_inference_seconds",
            "Duration of one batched onnxruntime call, by mode.",
            ["mode"],
            buckets=_LATENCY_BUCKETS,
            registry=self.registry,
        )
        self.camera_corrupt = Counter(
            "pose_camera_corrupt_rows",
            "Camera store rows met that do not parse or validate (left out of the list, 409 "
            "camera_corrupt for their id), by operation: check (at start), list, get, "
            "predict, stream.",
            ["operation"],
            registry=self.registry,
        )
        self.camera_store = Counter(
            "pose_camera_store_events",
            "Camera store events: integrity_failed (PRAGMA quick_check at start), "
            "store_changed (the file removed, replaced or truncated under the service).",
            ["event"],
            registry=self.registry,
        )

    def observe(self, mode: str, images: int, inference_s: float) -> None:
        """Count a request's images and time its batched network call."""
        self.images.labels(mode).inc(images)
        self.inference.labels(mode).observe(inference_s)

    def render(self) -> bytes:
        """The text exposition: this app's registry, or every worker's files."""
        if self.multiprocess_dir is None:
            return generate_latest(self.registry)
        merged = CollectorRegistry()
        MultiProcessCollector(merged, path=self.multiprocess_dir)
        return generate_latest(merged)
