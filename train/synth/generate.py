"""Writing synthetic data sets (SPEC section 7); `service.core.dataset` reads them.

A synthetic set is a folder:

* `images/NNNNN.png`: RGB images of the manifest's size;
* `labels.csv`: one row per image, columns `LABEL_COLUMNS` (`file` relative to the folder;
  class 0..8; camera centre and look-at target in cm, object frame; SPEC blur level; split
  train / val / test; roll in degrees and focal-length scale). Class 0 rows (no object) leave
  the camera columns empty;
* `manifest.json`: generator and version, profile, size [W, H], variant, blur, seed, count,
  jitter, per-split counts and per-split class counts.

`make_dataset` writes one set (class-balanced 60 / 20 / 20 splits, deterministic for a seed:
the same bytes whatever the number of worker processes) and `make_datasets` the 16 SPEC sets.
"""

from __future__ import annotations

import multiprocessing
import os
import shutil
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from multiprocessing.context import BaseContext
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from service.core.blur import BLUR_LEVELS
from service.core.dataset import (
    CORNER_COLUMNS,
    LABEL_COLUMNS,
    LABELS_FILE,
    SPLITS,
    DatasetError,
    write_labels,
    write_manifest,
)
from service.core.inputs import SIZES
from service.core.profile import Profile
from service.core.regions import NUM_CLASSES
from train.synth.background import BackgroundPool
from train.synth.render import VARIANTS, Renderer, View, draw_views

GENERATOR = "planar-pose data make"
GENERATOR_VERSION = "1.0"
SPLIT_FRACTIONS = (0.6, 0.2, 0.2)
MIN_COUNT = NUM_CLASSES
CHUNK = 250  # images per rendering task (and per random stream)
PNG_PARAMS = [cv2.IMWRITE_PNG_COMPRESSION, 0, cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_NONE]


@dataclass(frozen=True)
class DatasetSpec:
    """What to generate: variant C / noC, SPEC size 1 / 2, blur 0..3, count, seed, profile;
    `all_train`: every image in the train split (a training set selected on other sets' val
    split), not `SPLIT_FRACTIONS`."""

    variant: str
    size: int
    blur: int
    count: int
    seed: int
    profile: Profile
    jitter: bool = True
    all_train: bool = False

    def __post_init__(self) -> None:
        if self.variant not in VARIANTS:
            raise DatasetError(
                f"variant must be one of {', '.join(VARIANTS)}, got {self.variant!r}"
            )
        if self.size not in SIZES:
            raise DatasetError(f"size must be 1 (80x60) or 2 (160x120), got {self.size!r}")
        if self.blur not in BLUR_LEVELS:
            raise DatasetError(f"blur must be 0, 1, 2 or 3, got {self.blur!r}")
        if self.count < MIN_COUNT:
            raise DatasetError(
                f"count must be at least {MIN_COUNT} (one per class), got {self.count}"
            )

    @property
    def name(self) -> str:
        """Folder name in a grid, e.g. noC-s1-b2."""
        return f"{self.variant}-s{self.size}-b{self.blur}"

    @property
    def wh(self) -> tuple[int, int]:
        """Image size (W, H) in pixels."""
        return SIZES[self.size]


def balanced_assignment(
    count: int, rng: np.random.Generator, fractions: tuple[float, float, float] = SPLIT_FRACTIONS
) -> tuple[np.ndarray, np.ndarray]:
    """Classes int (N,) and split indices int (N,) (0 train, 1 val, 2 test), shuffled.

    Split sizes round(`fractions`[0] x N), round(`fractions`[1] x N), rest (60 %, 20 %, 20 %
    by default); inside each split the 9 classes differ by at most one image, and the split's
    extra images go to the classes with fewest so far, so the whole set is balanced too.
    """
    n_train, n_val = round(fractions[0] * count), round(fractions[1] * count)
    sizes = (n_train, n_val, count - n_train - n_val)
    totals = np.zeros(NUM_CLASSES, int)
    classes, splits = [], []
    for split, n in enumerate(sizes):
        per = np.full(NUM_CLASSES, n // NUM_CLASSES)
        extra = np.argsort(totals, kind="stable")[: n % NUM_CLASSES]
        per[extra] += 1
        totals += per
        classes.append(np.repeat(np.arange(NUM_CLASSES), per))
        splits.append(np.full(n, split))
    order = rng.permutation(count)
    return np.concatenate(classes)[order], np.concatenate(splits)[order]


@dataclass
class Plan:
    """Everything about a set except the pixels: one class, split and view (None for 0) each."""

    spec: DatasetSpec
    classes: np.ndarray
    splits: np.ndarray
    views: list[View | None] = field(repr=False)

    def rows(self, width: int) -> list[dict[str, Any]]:
        """labels.csv rows (see LABEL_COLUMNS); `width` = digits of the image numbers."""
        rows = []
        for i, (k, s, view) in enumerate(zip(self.classes, self.splits, self.views, strict=True)):
            row: dict[str, Any] = {c: "" for c in LABEL_COLUMNS}
            row |= {"file": image_name(i, width), "class": int(k), "blur": self.spec.blur}
            row["split"] = SPLITS[int(s)]
            if view is not None:
                row |= {f"cam_{a}": f"{v:.4f}" for a, v in zip("xyz", view.centre, strict=True)}
                row |= {f"target_{a}": f"{v:.4f}" for a, v in zip("xyz", view.target, strict=True)}
                row |= {
                    "roll_deg": f"{view.roll_deg:.3f}",
                    "focal_scale": f"{view.focal_scale:.4f}",
                    "k1": f"{view.k1:.4f}",
                }
                corners = view.object_corners(self.spec.profile, self.spec.wh).ravel()
                row |= {c: f"{v:.3f}" for c, v in zip(CORNER_COLUMNS, corners, strict=True)}
            rows.append(row)
        return rows


def plan_dataset(spec: DatasetSpec) -> Plan:
    """Classes, splits and cameras of a set, from its seed alone."""
    rng = np.random.default_rng(spec.seed)
    classes, splits = balanced_assignment(
        spec.count, rng, (1.0, 0.0, 0.0) if spec.all_train else SPLIT_FRACTIONS
    )
    present = classes > 0
    drawn = iter(draw_views(spec.profile, classes[present], spec.variant, rng))
    views = [next(drawn) if p else None for p in present]
    return Plan(spec, classes, splits, views)


def image_name(index: int, width: int) -> str:
    """Relative path of image `index`, e.g. images/00042.png."""
    return f"images/{index:0{width}d}.png"


_RENDERERS: dict[tuple[Any, ...], Renderer] = {}
MAX_RENDERERS = 32
_BACKGROUNDS: dict[tuple[tuple[int, int], Path], BackgroundPool] = {}


def backgrounds_for(profile: Profile, size: tuple[int, int]) -> BackgroundPool:
    """The background pool of the object's renders at `size` (W, H): the default pool
    without the sources that show the object's texture (`BackgroundPool.default`; checked by
    matching, their names in its `excluded`); the last one asked for is kept per process."""
    key = (size, profile.texture)
    if key not in _BACKGROUNDS:
        _BACKGROUNDS.clear()  # one pool at a time (a pool at 640x480 is GBs), and so
        _RENDERERS.clear()  # no renderer that holds another
        _BACKGROUNDS[key] = BackgroundPool.default(size, texture=profile.texture_rgb())
    return _BACKGROUNDS[key]


def _renderer(spec: DatasetSpec) -> Renderer:
    """One renderer per (profile, size, jitter, seed) and process; one background pool per
    size, texture and process (`backgrounds_for`)."""
    key = (spec.profile, spec.wh, spec.jitter, spec.seed)
    if key not in _RENDERERS:
        if len(_RENDERERS) >= MAX_RENDERERS:  # forget the oldest
            del _RENDERERS[next(iter(_RENDERERS))]
        pool = backgrounds_for(spec.profile, spec.wh)
        _RENDERERS[key] = Renderer(spec.profile, spec.wh, spec.jitter, pool, seed=spec.seed)
    return _RENDERERS[key]


@dataclass(frozen=True)
class Chunk:
    """A rendering task: images chunk * CHUNK ... of a set, their views (None for class 0),
    and the folder to write them to (None: return the arrays)."""

    spec: DatasetSpec
    chunk: int
    views: tuple[View | None, ...]
    out: Path | None = None


def chunks_of(plan: Plan, out: Path | None) -> list[Chunk]:
    """The rendering tasks of a planned set."""
    n = plan.spec.count
    return [
        Chunk(plan.spec, c, tuple(plan.views[c * CHUNK : (c + 1) * CHUNK]), out)
        for c in range(-(-n // CHUNK))
    ]


def render_chunk(task: Chunk) -> Iterator[tuple[int, np.ndarray]]:
    """(index, RGB uint8 [H, W, 3]) of the images of one chunk.

    Each chunk has its own random stream seeded by (seed, chunk), so images do not depend on
    which process renders them.
    """
    renderer = _renderer(task.spec)
    rng = np.random.default_rng([task.spec.seed, task.chunk])
    for j, view in enumerate(task.views):
        yield task.chunk * CHUNK + j, renderer.render(view, task.spec.blur, rng)


def _run_task(task: Chunk) -> tuple[int, np.ndarray | None]:
    """Render one chunk; write its PNGs (returns None) or return the images [n, H, W, 3]."""
    images = []
    width = _digits(task.spec.count)
    for i, rgb in render_chunk(task):
        if task.out is None:
            images.append(rgb)
            continue
        ok, buf = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), PNG_PARAMS)
        if not ok:
            raise OSError(f"PNG encoding failed for image {i}")
        (task.out / image_name(i, width)).write_bytes(buf.tobytes())
    return task.chunk, np.stack(images) if images else None


def _digits(count: int) -> int:
    return max(5, len(str(count - 1)))


def _init_worker() -> None:
    cv2.setNumThreads(1)


def run_tasks(
    tasks: list[Chunk], workers: int, progress: Callable[[int], None] | None = None
) -> Iterator[tuple[int, np.ndarray | None]]:
    """Run rendering tasks in `workers` processes (1: in this process), yielding
    (chunk, images) in task order; `progress(n_images)` after each task."""

    def done(task: Chunk) -> int:
        return len(task.views)

    if workers <= 1 or len(tasks) <= 1:
        for task in tasks:
            result = _run_task(task)
            if progress:
                progress(done(task))
            yield result
        return
    pool = _executor(workers)
    try:
        for task, result in zip(tasks, pool.map(_run_task, tasks), strict=True):
            if progress:
                progress(done(task))
            yield result
    except BrokenProcessPool:
        _EXECUTORS.pop(workers, None)
        raise


_EXECUTORS: dict[int, ProcessPoolExecutor] = {}


def _executor(workers: int) -> ProcessPoolExecutor:
    """A process pool kept for the life of this process, so that its workers keep their
    renderers (textures, backgrounds) warm between data sets."""
    if workers not in _EXECUTORS:
        # Not "fork": a child forked after OpenCV started its thread pool can deadlock.
        context: BaseContext
        if "forkserver" in multiprocessing.get_all_start_methods():
            context = multiprocessing.get_context("forkserver")
            context.set_forkserver_preload([__name__])
        else:
            context = multiprocessing.get_context("spawn")
        _EXECUTORS[workers] = ProcessPoolExecutor(
            workers, mp_context=context, initializer=_init_worker
        )
    return _EXECUTORS[workers]


def default_workers() -> int:
    """Worker processes: the CPU cores this process may use."""
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else 1)


def check_outputs(folders: list[Path], overwrite: bool) -> None:
    """Raise DatasetError if a folder is a file, or is not empty and `overwrite` is off."""
    if len(set(folders)) != len(folders):
        raise DatasetError("two data sets would be written to the same folder")
    for out in folders:
        if out.exists() and not out.is_dir():
            raise DatasetError(f"{out} exists and is not a folder")
        if out.is_dir() and any(out.iterdir()) and not overwrite:
            raise DatasetError(f"{out} exists and is not empty (use --overwrite to replace it)")


def prepare_folder(out: Path, overwrite: bool) -> None:
    """Make `out` ready for a new set: refuse a non-empty folder unless `overwrite`, and then
    only if it holds a data set (manifest.json, labels.csv or images/), which is deleted."""
    if out.exists() and not out.is_dir():
        raise DatasetError(f"{out} exists and is not a folder")
    if out.is_dir() and any(out.iterdir()):
        if not overwrite:
            raise DatasetError(f"{out} exists and is not empty (use --overwrite to replace it)")
        if not any((out / n).exists() for n in ("manifest.json", "labels.csv", "images")):
            raise DatasetError(f"{out} is not a data set folder; refusing to delete it")
        shutil.rmtree(out)
    (out / "images").mkdir(parents=True, exist_ok=True)


def _manifest(plan: Plan) -> dict[str, Any]:
    spec = plan.spec
    split_classes = {
        name: np.bincount(plan.classes[plan.splits == s], minlength=NUM_CLASSES).tolist()
        for s, name in enumerate(SPLITS)
    }
    return {
        "generator": GENERATOR,
        "generator_version": GENERATOR_VERSION,
        "profile": spec.profile.manifest_entry(),
        "size": list(spec.wh),
        "variant": spec.variant,
        "blur": spec.blur,
        "seed": spec.seed,
        "count": spec.count,
        "jitter": spec.jitter,
        "counts": {name: int(np.sum(plan.splits == s)) for s, name in enumerate(SPLITS)},
        "class_counts": np.bincount(plan.classes, minlength=NUM_CLASSES).tolist(),
        "split_class_counts": split_classes,
    }


def make_datasets(
    jobs: list[tuple[DatasetSpec, Path]],
    overwrite: bool = False,
    workers: int = 1,
    progress: Callable[[int], None] | None = None,
) -> list[dict[str, Any]]:
    """Write several data sets (`spec`, folder), sharing one pool of `workers` processes.

    All folders are checked before anything is written. Returns their manifests.
    """
    check_outputs([out for _, out in jobs], overwrite)
    plans = []
    for spec, out in jobs:
        prepare_folder(out, overwrite)
        plans.append(plan_dataset(spec))
    tasks = [t for plan, (_, out) in zip(plans, jobs, strict=True) for t in chunks_of(plan, out)]
    for _ in run_tasks(tasks, workers, progress):
        pass
    manifests = []
    for plan, (spec, out) in zip(plans, jobs, strict=True):
        write_labels(out / LABELS_FILE, plan.rows(_digits(spec.count)))
        manifests.append(write_manifest(out, _manifest(plan)))
    return manifests


def make_dataset(
    out: Path,
    spec: DatasetSpec,
    overwrite: bool = False,
    workers: int = 1,
    progress: Callable[[int], None] | None = None,
) -> dict[str, Any]:
    """Write one data set to `out` (see the module doc); return its manifest."""
    return make_datasets([(spec, out)], overwrite, workers, progress)[0]


def grid_specs(count: int, seed: int, profile: Profile, jitter: bool = True) -> list[DatasetSpec]:
    """The 16 SPEC sets {C, noC} x size {1, 2} x blur {0..3}; set i gets seed `seed + i`."""
    combos = [(v, s, b) for v in ("C", "noC") for s in SIZES for b in BLUR_LEVELS]
    return [
        DatasetSpec(v, s, b, count, seed + i, profile, jitter) for i, (v, s, b) in enumerate(combos)
    ]


def render_in_memory(spec: DatasetSpec, workers: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Render a whole set without writing it: images uint8 [N, H, W, 3] RGB, classes (N,)."""
    plan = plan_dataset(spec)
    images = np.concatenate([im for _, im in run_tasks(chunks_of(plan, None), workers)])
    return images, plan.classes.astype(np.int64)
