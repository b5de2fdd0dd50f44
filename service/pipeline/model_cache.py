"""The loaded models of one worker process: graphs load on first use and the least recently
used are unloaded beyond a memory budget (`POSE_MODEL_MEMORY_MB`).

What a loaded model costs is estimated from its file before it is loaded (`estimated_bytes`:
its nodes and weights, `service.pipeline.onnx_file.read_graph_size`), not measured on the process,
whose resident size other threads move at the same time (a decode of a large upload) and
which does not shrink when a session is freed (glibc keeps the pages for the next one). A
request holds the predictor it got: an unloaded model's session is freed once the last
request using it ends.
"""

from __future__ import annotations

import fcntl
import hashlib
import logging
import os
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import onnxruntime as ort
from prometheus_client import Counter, Gauge, Histogram
from prometheus_client.multiprocess import mark_process_dead

from service.metrics import Metrics
from service.pipeline.model import ModelLoadError
from service.pipeline.onnx_file import OnnxFileError, read_graph_size
from service.pipeline.predictor import Predictor, give_back_memory
from service.workers import alive

log = logging.getLogger("uvicorn.error.pose")

Signature = tuple[int, int, int]  # (size, mtime_ns, inode)

#: A session's resident bytes per byte of the graph's weights (the weights, their prepacked
#: copies for the kernels) and per node (kernel, plan, graph structure), and per session:
#: fitted to the shipped models under onnxruntime 1.32 (chessboard-corners-160x120: 5,596
#: nodes and 1.4 MB of weights, 20.2 MiB measured, 20.5 MiB estimated; the book's corners,
#: 9,730 nodes: 33.3 / 33.5 MiB; chessboard-spec-160x120, 21 nodes, 12.5 MB: 20.7 / 21.7 MiB),
#: each after a zoom pass with the shared CPU arena; `benchmarks/bench_models.py` prints
#: the estimate against the resident size of a worker.
BYTES_PER_WEIGHT_BYTE = 1.7
BYTES_PER_NODE = 3300
BYTES_PER_SESSION = 512 * 1024


def estimated_bytes(path: Path) -> int:
    """The resident bytes a session of the ONNX file `path` takes once loaded and run;
    ModelLoadError for a file that is not ONNX."""
    try:
        graph = read_graph_size(path)
    except OnnxFileError as exc:
        raise ModelLoadError(f"{path}: not a loadable ONNX model ({exc})") from None
    except OSError:
        raise ModelLoadError(f"model file not found: {path}") from None
    return int(
        BYTES_PER_WEIGHT_BYTE * graph.initializer_bytes
        + BYTES_PER_NODE * graph.nodes
        + BYTES_PER_SESSION
    )


@dataclass(frozen=True)
class ModelFile:
    """A served model as listed: its name, file, the file's state and its card (read without
    loading the graph)."""

    name: str
    path: Path
    signature: Signature
    card: dict[str, Any]

    @property
    def key(self) -> tuple[str, str, Signature]:
        """What a loaded session is kept under: a changed file is another model."""
        return (self.name, str(self.path), self.signature)

    @property
    def input_size(self) -> tuple[int, int] | None:
        """(W, H) from the card, None where it does not state a usable one."""
        size = self.card.get("input")
        if not isinstance(size, list | tuple) or len(size) != 2:
            return None
        if all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in size):
            return (int(size[0]), int(size[1]))
        return None


class ModelMetrics:
    """The cache's Prometheus series in the app's registry (summed over live workers)."""

    def __init__(self, metrics: Metrics) -> None:
        registry = metrics.registry
        self.loads = Counter(
            "pose_model_loads",
            "Graphs loaded into onnxruntime, by result (ok, error).",
            ["result"],
            registry=registry,
        )
        self.load_seconds = Histogram(
            "pose_model_load_seconds",
            "Time to load one graph.",
            buckets=(0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0),
            registry=registry,
        )
        self.hits = Counter(
            "pose_model_cache_hits", "Requests whose model was loaded.", registry=registry
        )
        self.misses = Counter(
            "pose_model_cache_misses", "Requests that loaded their model.", registry=registry
        )
        self.evictions = Counter(
            "pose_model_cache_evictions",
            "Models unloaded to stay within POSE_MODEL_MEMORY_MB.",
            registry=registry,
        )
        self.loaded_bytes = Gauge(
            "pose_model_loaded_bytes",
            "Estimated resident bytes of the loaded models (summed over live workers).",
            multiprocess_mode="livesum",
            registry=registry,
        )
        self.loaded_models = Gauge(
            "pose_models_loaded",
            "Models loaded (summed over live workers).",
            multiprocess_mode="livesum",
            registry=registry,
        )
        if metrics.multiprocess_dir is not None:
            forget_dead_workers(Path(metrics.multiprocess_dir))


def forget_dead_workers(folder: Path) -> None:
    """Drop the live gauges of worker processes that died (a replaced worker's files would
    count its loaded models for good otherwise)."""
    for file in folder.glob("gauge_live*_*.db"):
        pid = file.stem.rsplit("_", 1)[-1]
        if pid.isdigit() and not alive(int(pid)):
            mark_process_dead(int(pid), str(folder))


@dataclass(frozen=True)
class _Loaded:
    predictor: Predictor
    size: int  # estimated bytes
    quick: bool = False  # its graph unoptimized, until `_optimize_loaded` replaces it


def optimized_path(folder: Path, path: Path) -> Path:
    """Where the optimized graph (ORT format) of the ONNX file `path` is kept in `folder`:
    named by the file's content (copies share it) and the onnxruntime version."""
    digest = hashlib.sha256(path.read_bytes()).hexdigest()[:32]
    return folder / f"{digest}-onnxruntime-{ort.__version__}.ort"


@contextmanager
def writing(target: Path | None) -> Iterator[None]:
    """Hold the lock on writing the optimized graph `target` (a file lock beside it, shared
    by the threads and the worker processes): one optimizes a graph, the others then read
    what it wrote. OSError when the lock file cannot be made."""
    if target is None:
        yield
        return
    with target.with_name(target.name + ".lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        yield


class ModelCache:
    """Predictors of model files by `ModelFile.key`, least recently used unloaded beyond
    `budget` bytes (never a pinned one, nor the one just loaded); a file that failed to load
    is not tried again until it changes. Thread-safe; different models load in parallel,
    one model once. `load(file, optimized, optimize)` makes a predictor, `optimized` the file
    of its optimized graph in `optimized_dir` (None: no such folder), `optimize` as in
    `PoseModel.load`.

    A model whose optimized graph is not written yet is loaded unoptimized (4x faster: a
    cold model's first answer within a second) and optimized at once in a thread of the
    lowest priority, which then puts the optimized graph in its place."""

    def __init__(
        self,
        budget: int,
        load: Callable[[ModelFile, Path | None, bool], Predictor],
        metrics: ModelMetrics | None = None,
        optimized_dir: Path | None = None,
    ) -> None:
        self.budget, self._load, self.metrics = budget, load, metrics
        self.optimized_dir = optimized_dir
        self._optimized: dict[tuple[str, str, Signature], Path] = {}
        self._loaded: OrderedDict[tuple[str, str, Signature], _Loaded] = OrderedDict()
        self._failed: dict[tuple[str, str, Signature], str] = {}
        self._locks: dict[tuple[str, str, Signature], threading.Lock] = {}
        self._lock = threading.Lock()
        self.pinned: set[tuple[str, str, Signature]] = set()

    def peek(self, file: ModelFile, count: bool = True) -> Predictor | None:
        """The loaded predictor of `file` (now the most recent; `count`: a cache hit), else
        None."""
        with self._lock:
            loaded = self._loaded.get(file.key)
            if loaded is None:
                return None
            self._loaded.move_to_end(file.key)
        if count and self.metrics is not None:
            self.metrics.hits.inc()
        return loaded.predictor

    def get(self, file: ModelFile, count: bool = True) -> Predictor:
        """The predictor of `file`, loaded now if it is not (blocking: call it in a thread;
        `count`: a request's, counted as a cache hit or miss); ModelLoadError when the file
        does not load."""
        found = self.peek(file, count)
        if found is not None:
            return found
        with self._lock:
            lock = self._locks.setdefault(file.key, threading.Lock())
        with lock:  # one load per model; the others wait for it
            with self._lock:
                loaded = self._loaded.get(file.key)
                failed = self._failed.get(file.key)
            if loaded is not None:
                return loaded.predictor
            if failed is not None:
                raise ModelLoadError(failed)
            if count and self.metrics is not None:
                self.metrics.misses.inc()
            return self._load_now(file)

    def _load_now(self, file: ModelFile) -> Predictor:
        start = time.perf_counter()
        try:
            size = estimated_bytes(file.path)
            self._make_room(size, file.key)
            optimized = self.optimized(file)
            quick = optimized is not None and not optimized.is_file()
            predictor = self._load(file, optimized, not quick)
        except ModelLoadError as exc:
            with self._lock:
                self._failed[file.key] = str(exc)
            self._count_load("error", start)
            log.error("model %s not loaded: %s", file.name, exc)
            raise
        with self._lock:
            self._loaded[file.key] = _Loaded(predictor, size, quick)
            if quick:
                # not a daemon: the interpreter's exit waits for it (onnxruntime aborts the
                # process when it exits with a thread inside a session's creation)
                threading.Thread(target=self._optimize_loaded, args=(file,), daemon=False).start()
        self._count_load("ok", start)
        self._make_room(0, file.key)  # others may have loaded meanwhile
        log.info(
            "model %s loaded%s (%.0f MB estimated) in %.2f s",
            file.name,
            " unoptimized" if quick else "",
            size / 2**20,
            time.perf_counter() - start,
        )
        return predictor

    def _optimize_loaded(self, file: ModelFile) -> None:
        """Load `file` optimized (its optimized graph read, or written if it is still not
        there) at the lowest priority, and put it in the place of its unoptimized load
        unless that was unloaded meanwhile."""
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 19)  # this thread only
        target = self.optimized(file)
        try:
            try:
                with writing(target):
                    predictor = self._load(file, target, True)
            except OSError:  # a folder it cannot write to: optimized all the same, not kept
                predictor = self._load(file, None, True)
        except ModelLoadError as exc:  # the unoptimized graph loaded: it stays
            log.warning("model %s not optimized: %s", file.name, exc)
            return
        with self._lock:
            loaded = self._loaded.get(file.key)
            if loaded is None or not loaded.quick:
                return
            self._loaded[file.key] = _Loaded(predictor, loaded.size)
        log.info("model %s now runs its optimized graph", file.name)

    def optimized(self, file: ModelFile) -> Path | None:
        """The file of `file`'s optimized graph (None: no folder for them, or unreadable);
        the file's content hashed once per file state."""
        if self.optimized_dir is None:
            return None
        with self._lock:
            known = self._optimized.get(file.key)
        if known is not None:
            return known
        try:
            found = optimized_path(self.optimized_dir, file.path)
        except OSError:
            return None
        with self._lock:
            self._optimized[file.key] = found
        return found

    def prepare(self, file: ModelFile) -> bool:
        """Write `file`'s optimized graph unless it is there (a session made and dropped,
        not kept); True when one was written."""
        target = self.optimized(file)
        if target is None or target.exists() or self.failure(file) is not None:
            return False
        try:
            with writing(target):
                if target.exists():  # written meanwhile
                    return False
                self._load(file, target, True)
        except (ModelLoadError, OSError):
            return False
        return True

    def _count_load(self, result: str, start: float) -> None:
        if self.metrics is not None:
            self.metrics.loads.labels(result).inc()
            self.metrics.load_seconds.observe(time.perf_counter() - start)
            self._update_gauges()

    def _make_room(self, size: int, keep: tuple[str, str, Signature]) -> None:
        """Unload the least recently used models (not pinned, not `keep`) until the loaded
        ones and `size` more fit in the budget, or none is left to unload."""
        evicted = []
        with self._lock:
            total = size + sum(v.size for v in self._loaded.values())
            for key in list(self._loaded):
                if total <= self.budget:
                    break
                if key in self.pinned or key == keep:
                    continue
                total -= self._loaded.pop(key).size
                evicted.append(key[0])
        if evicted:
            log.info("models unloaded (memory budget): %s", ", ".join(evicted))
            if self.metrics is not None:
                self.metrics.evictions.inc(len(evicted))
                self._update_gauges()
            give_back_memory()

    def retain(self, files: list[ModelFile]) -> None:
        """Forget the loaded and failed models of files no longer listed (replaced, gone)."""
        keep = {f.key for f in files}
        with self._lock:
            dropped = [k for k in self._loaded if k not in keep]
            for key in dropped:
                del self._loaded[key]
            for key in [k for k in self._failed if k not in keep]:
                del self._failed[key]
            for key in [k for k in self._locks if k not in keep]:
                del self._locks[key]
            for key in [k for k in self._optimized if k not in keep]:
                del self._optimized[key]
            self.pinned &= keep
        if dropped:
            self._update_gauges()
            give_back_memory()

    def is_loaded(self, file: ModelFile) -> bool:
        with self._lock:
            return file.key in self._loaded

    def failure(self, file: ModelFile) -> str | None:
        """Why `file` did not load, None if it did or was not tried."""
        with self._lock:
            return self._failed.get(file.key)

    @property
    def loaded_bytes(self) -> int:
        with self._lock:
            return sum(v.size for v in self._loaded.values())

    def loaded_names(self) -> list[str]:
        """Names of the loaded models, least recently used first."""
        with self._lock:
            return [key[0] for key in self._loaded]

    def _update_gauges(self) -> None:
        if self.metrics is not None:
            with self._lock:
                count, size = len(self._loaded), sum(v.size for v in self._loaded.values())
            self.metrics.loaded_models.set(count)
            self.metrics.loaded_bytes.set(size)
