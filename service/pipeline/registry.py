"""The served models: every `<name>.onnx` of the model folder, listed with its card at once,
its graph loaded on first use (`service.pipeline.model_cache`: least recently used unloaded beyond
`POSE_MODEL_MEMORY_MB`); the default model is loaded with the list and never unloaded.

A reload reads the folder again and swaps the name -> file mapping in one assignment: a
request holds the Predictor it started with, so requests in flight finish on the old session.
Files whose size, mtime and inode are unchanged keep their entry (and session, if loaded); a
new or changed file has its card read (not its graph), except the default model's and a model
loaded at the time, which load at once: a graph that fails to load then keeps the previous
session (when it had one) and is reported. A file whose graph fails at its first use answers
503 `model_unavailable` and is reported until it changes. A file that disappears keeps its
entry for `POSE_MODEL_GRACE_S` seconds (reported meanwhile), so that an `rm` then a slow `cp`
leaves no gap; if no loadable file of that name comes back by then, the model is dropped.
Replace a model file atomically all the same (write a temporary file in the same folder,
then rename it over the old one; or swap the symlink of a Kubernetes volume): a `cp` over
the file is read while half written, refused, and only the next look loads it.
"""

from __future__ import annotations

import atexit
import fcntl
import functools
import logging
import os
import re
import shutil
import tempfile
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import MappingProxyType

from service.metrics import Metrics
from service.pipeline.model import ModelLoadError, PoseModel, read_card
from service.pipeline.model_cache import ModelCache, ModelFile, ModelMetrics, Signature
from service.pipeline.predictor import Predictor
from service.settings import Settings

log = logging.getLogger("uvicorn.error.pose")

#: Names usable in a URL path segment.
NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")
#: A name /v1/models/{name}/... also answers to with the default model (its name until 3.10.0).
DEFAULT_ALIAS = "default"
#: Seconds between two tries of a worker to become the one that writes optimized graphs.
PREPARE_RETRY_S = 5.0
#: Seconds a closing registry waits for the graph being optimized in the background.
PREPARE_JOIN_S = 5.0


@functools.cache
def process_optimized_folder() -> Path:
    """The optimized graphs' folder of a process served without a runtime folder (one
    worker): shared by its registries (an app made again reads the graphs written before),
    removed at the process's exit."""
    folder = Path(tempfile.mkdtemp(prefix="planar-pose-optimized-"))
    atexit.register(shutil.rmtree, folder, ignore_errors=True)
    return folder


@dataclass(frozen=True)
class ReloadReport:
    """What a (re)load did: names now served, new or changed files taken (their cards read;
    the default's and loaded models' graphs loaded too), dropped, and the files refused."""

    models: list[str]
    loaded: list[str]
    removed: list[str]
    problems: dict[str, str] = field(default_factory=dict)


def _signature(path: Path) -> Signature:
    st = path.stat()
    return (st.st_size, st.st_mtime_ns, st.st_ino)


class UnknownModel(KeyError):
    """No model of that name is served."""

    def __init__(self, name: str, known: list[str]) -> None:
        super().__init__(name)
        self.name, self.known = name, known


class ModelRegistry:
    """name -> model file for the configured files, their graphs loaded on demand into a
    `ModelCache`; thread-safe reloads."""

    def __init__(self, settings: Settings, metrics: Metrics | None = None) -> None:
        self.settings = settings
        self._served: Mapping[str, ModelFile] = MappingProxyType({})
        self._lock = threading.Lock()
        self._problems: dict[str, str] = {}
        self._gone: dict[str, float] = {}  # name -> time.monotonic() its file was first missed
        optimized = settings.optimized_dir or (
            process_optimized_folder()
            if settings.runtime_dir is None
            else settings.runtime_dir / "optimized"
        )
        optimized.mkdir(parents=True, exist_ok=True)
        self.cache = ModelCache(
            settings.model_memory_bytes,
            self._load,
            None if metrics is None else ModelMetrics(metrics),
            optimized,
        )
        self._prepare = threading.Event()
        self._closed = threading.Event()
        self._preparer: threading.Thread | None = None

    def files(self) -> dict[str, Path]:
        """The model files to serve, by name (file stem; POSE_MODEL_PATH as the default)."""
        s = self.settings
        found: dict[str, Path] = {}
        if s.model_path is None or s.model_dir is not None:
            folder = s.resolved_model_dir
            if folder.is_dir():
                found = {p.stem: p for p in sorted(folder.glob("*.onnx")) if p.is_file()}
        if s.model_path is not None:
            found[s.default_model] = s.model_path
        return found

    def folder_signature(self) -> tuple[tuple[str, Signature], ...]:
        """Cheap state of the files (for the folder watcher)."""
        out = []
        for name, path in self.files().items():
            try:
                out.append((name, _signature(path)))
            except OSError:
                continue
        return tuple(out)

    def reload(self) -> ReloadReport:
        """Take new and changed files, drop vanished ones, keep the rest; swap atomically."""
        with self._lock:
            old, new, taken, problems = self._served, {}, [], {}
            for name, path in self.files().items():
                if not NAME_PATTERN.fullmatch(name):
                    problems[name] = (
                        f"{path.name}: name not usable in a URL ({NAME_PATTERN.pattern})"
                    )
                    continue
                try:
                    signature = _signature(path)
                    if name in old and (old[name].signature, old[name].path) == (signature, path):
                        new[name] = old[name]
                        continue
                    new[name] = self._take(ModelFile(name, path, signature, read_card(path)), old)
                    taken.append(name)
                except (ModelLoadError, OSError) as exc:
                    problems[name] = (
                        str(exc)
                        if isinstance(exc, ModelLoadError)
                        else (f"model file not found: {path}")
                    )
                    if name in old:  # keep serving the last good file
                        new[name] = old[name]
            self._keep_vanished(old, new, problems)
            self._served = MappingProxyType(dict(sorted(new.items())))
            default = self._served.get(self.settings.default_model)
            self.cache.pinned = set() if default is None else {default.key}
            self.cache.retain(list(self._served.values()))
            self._problems = problems
        for name, problem in problems.items():
            log.error("model %s not loaded: %s", name, problem)
        removed = sorted(set(old) - set(new))
        if taken or removed:
            log.info("models taken: %s; removed: %s", taken or "-", removed or "-")
        return ReloadReport(sorted(new), taken, removed, self.problems)

    def _take(self, file: ModelFile, old: Mapping[str, ModelFile]) -> ModelFile:
        """`file`, its graph loaded now if it is the default model's, replaces a loaded
        model, or has a card without its input size (then the graph's goes in the card);
        ModelLoadError when that load fails."""
        loaded = file.name in old and self.cache.is_loaded(old[file.name])
        if file.name != self.settings.default_model and not loaded and file.input_size:
            return file
        model = self.cache.get(file, count=False).model
        if file.input_size is None:
            return replace(file, card={**file.card, "input": list(model.input_size)})
        return file

    def _keep_vanished(
        self, old: Mapping[str, ModelFile], new: dict[str, ModelFile], problems: dict[str, str]
    ) -> None:
        """Keep serving the models of `old` whose files are gone (not in `new`) until
        `model_grace_s` has passed since they were first missed, reported in `problems`."""
        now, grace = time.monotonic(), self.settings.model_grace_s
        for name in set(self._gone) - set(old):
            del self._gone[name]
        for name in new:
            self._gone.pop(name, None)
        for name in sorted(set(old) - set(new)):
            since = self._gone.setdefault(name, now)
            if now - since < grace:
                new[name] = old[name]
                problems[name] = (
                    f"model file gone: {old[name].path}; the "
                    f"{'loaded ' if self.cache.is_loaded(old[name]) else ''}model "
                    f"answers until a new file arrives or for {grace:g} s "
                    f"({grace - (now - since):.0f} s left)"
                )
            else:
                del self._gone[name]

    def grace_ends(self) -> float | None:
        """When (time.monotonic()) the grace of the first vanished model ends, or None."""
        if not self._gone:
            return None
        return min(self._gone.values()) + self.settings.model_grace_s

    def _load(self, file: ModelFile, optimized: Path | None, optimize: bool) -> Predictor:
        s = self.settings
        model = PoseModel.load(
            file.path,
            s.intra_op_threads,
            s.inter_op_threads,
            card=file.card,
            optimized=optimized,
            optimize=optimize,
        )
        return Predictor(model, s)

    def prepare_in_background(self) -> None:
        """Write the optimized graph of every served model, one at a time, in a thread of
        the lowest priority (after each reload again, for the new files): a model's first
        load then takes the fast path. With several workers one does it (a file lock in the
        runtime folder; another takes over if it dies)."""
        self._prepare.set()
        if self._preparer is None:
            self._preparer = threading.Thread(target=self._prepare_all, daemon=True)
            self._preparer.start()

    def _prepare_all(self) -> None:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 19)  # this thread only
        folder = self.cache.optimized_dir
        assert folder is not None
        with (folder / "prepare.lock").open("w") as lock:
            while True:
                try:
                    fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
                    break
                except OSError:
                    if self._closed.wait(PREPARE_RETRY_S):
                        return
            while self._prepare.wait() and not self._closed.is_set():
                self._prepare.clear()
                written = sum(
                    self.cache.prepare(f)
                    for f in list(self._served.values())
                    if not self._closed.is_set()
                )
                if written:
                    log.info("optimized graphs written: %d", written)

    def close(self) -> None:
        """Stop preparing (the graph being written is finished: a thread inside onnxruntime
        at the interpreter's exit aborts it)."""
        self._closed.set()
        self._prepare.set()
        if self._preparer is not None:
            self._preparer.join(PREPARE_JOIN_S)

    @property
    def problems(self) -> dict[str, str]:
        """Files refused at the last reload, and served files whose graph failed to load."""
        failed = {
            name: reason
            for name, file in self._served.items()
            if (reason := self.cache.failure(file)) is not None
        }
        return {**failed, **self._problems}

    @property
    def names(self) -> list[str]:
        return list(self._served)

    def entries(self) -> Mapping[str, ModelFile]:
        """A snapshot of what is served now (cards; graphs loaded or not)."""
        return self._served

    def file(self, name: str) -> ModelFile:
        """The served file of `name` (`DEFAULT_ALIAS`: the default model, unless a model has
        that name), or UnknownModel listing the known names."""
        if name == DEFAULT_ALIAS and name not in self._served:
            name = self.settings.default_model
        found = self._served.get(name)
        if found is None:
            raise UnknownModel(name, self.names)
        return found

    def loaded(self, name: str) -> Predictor | None:
        """The predictor of `name` if its graph is loaded (no waiting), else None;
        UnknownModel for a name not served."""
        return self.cache.peek(self.file(name))

    def get(self, name: str) -> Predictor:
        """The predictor of `name`, its graph loaded first if it is not (blocking: run it in
        a thread); UnknownModel, or ModelLoadError when the graph does not load."""
        return self.cache.get(self.file(name))

    def default(self, count: bool = False) -> Predictor | None:
        """The default model's predictor (loaded with the list; `count`: as a cache hit)."""
        found = self._served.get(self.settings.default_model)
        return None if found is None else self.cache.peek(found, count)
