"""The served models: every `<name>.onnx` of the model folder (with its card), one Predictor
each, reloaded without a restart.

A reload builds a new name -> Predictor mapping and swaps it in one assignment: a request holds
the Predictor it started with, so requests in flight finish on the old session. Files whose
size, mtime and inode are unchanged keep their session; a file that fails to load keeps its
previous session (when it had one) and is reported. A file that disappears keeps its session
for `POSE_MODEL_GRACE_S` seconds (reported meanwhile), so that an `rm` then a slow `cp`
leaves no gap; if no loadable file of that name comes back by then, the model is dropped.
Replace a model file atomically all the same (write a temporary file in the same folder,
then rename it over the old one; or swap the symlink of a Kubernetes volume): a `cp` over
the file is read while half written, refused, and only the next look loads it.
"""

from __future__ import annotations

import logging
import re
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType

from service.model import ModelLoadError, PoseModel
from service.predictor import Predictor
from service.settings import Settings

log = logging.getLogger("uvicorn.error.pose")

#: Names usable in a URL path segment.
NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")
#: A name /v1/models/{name}/... also answers to with the default model (its name until 3.10.0).
DEFAULT_ALIAS = "default"

Signature = tuple[int, int, int]  # (size, mtime_ns, inode)


@dataclass(frozen=True)
class Served:
    """One served model and the file state it was loaded from."""

    predictor: Predictor
    signature: Signature


@dataclass(frozen=True)
class ReloadReport:
    """What a (re)load did: names now served, loaded anew, dropped, and the files refused."""

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
    """name -> Predictor for the configured model files; thread-safe reloads."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self._served: Mapping[str, Served] = MappingProxyType({})
        self._lock = threading.Lock()
        self.problems: dict[str, str] = {}
        self._gone: dict[str, float] = {}  # name -> time.monotonic() its file was first missed

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
        """Load new and changed files, drop vanished ones, keep the rest; swap atomically."""
        with self._lock:
            old, new, loaded, problems = self._served, {}, [], {}
            for name, path in self.files().items():
                if not NAME_PATTERN.fullmatch(name):
                    problems[name] = (
                        f"{path.name}: name not usable in a URL ({NAME_PATTERN.pattern})"
                    )
                    continue
                try:
                    signature = _signature(path)
                    if name in old and old[name].signature == signature:
                        new[name] = old[name]
                        continue
                    new[name] = Served(self._load(path), signature)
                    loaded.append(name)
                except (ModelLoadError, OSError) as exc:
                    problems[name] = (
                        str(exc)
                        if isinstance(exc, ModelLoadError)
                        else (f"model file not found: {path}")
                    )
                    if name in old:  # keep serving the last good session
                        new[name] = old[name]
            self._keep_vanished(old, new, problems)
            self._served = MappingProxyType(dict(sorted(new.items())))
            self.problems = problems
        for name, problem in problems.items():
            log.error("model %s not loaded: %s", name, problem)
        removed = sorted(set(old) - set(new))
        if loaded or removed:
            log.info("models loaded: %s; removed: %s", loaded or "-", removed or "-")
        return ReloadReport(sorted(new), loaded, removed, problems)

    def _keep_vanished(
        self, old: Mapping[str, Served], new: dict[str, Served], problems: dict[str, str]
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
                    f"model file gone: {old[name].predictor.model.path}; the loaded model "
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

    def _load(self, path: Path) -> Predictor:
        s = self.settings
        model = PoseModel.load(path, s.intra_op_threads, s.inter_op_threads)
        return Predictor(model, s)

    @property
    def names(self) -> list[str]:
        return list(self._served)

    def predictors(self) -> Mapping[str, Predictor]:
        """A snapshot of what is served now."""
        return {name: served.predictor for name, served in self._served.items()}

    def get(self, name: str) -> Predictor:
        """The predictor of `name` (`DEFAULT_ALIAS`: the default model, unless a model has
        that name), or UnknownModel listing the known names."""
        if name == DEFAULT_ALIAS and name not in self._served:
            name = self.settings.default_model
        served = self._served.get(name)
        if served is None:
            raise UnknownModel(name, self.names)
        return served.predictor

    def default(self) -> Predictor | None:
        served = self._served.get(self.settings.default_model)
        return served.predictor if served is not None else None
