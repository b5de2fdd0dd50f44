"""The comparison, orchestrated: CNN (ONNX) vs the classical peers, and whole / sliding /
proposals, measured in one run on one machine, so times compare as ratios:

* per data set (size, blur, synthetic or real): accuracy of each ONNX model whose input size
  and object match the data set (with `resize`, of each model of its object: images of
  another size are resized to its input as the service resizes an upload;
  `train.network.evaluate.model_predictor` + `evaluate_predictor`: the service's
  preprocessing, batches of 64), with `given_fx` also of each model whose graph takes the
  camera's focal length given the fx of the camera the chessboard detector is given (method
  `<model> + fx`), and of each peer
  (`train.compare.peers`: OpenCV's chessboard detector on chessboard sets, the feature
  baseline tuned on the set's val split), ms per image of each and their ratio; on real sets
  whose stored photographs are here, the chessboard detector on those for reference;
* detection variants (SPEC section 9, `train.compare.detection`).

Outputs: the Markdown report (default docs/comparison.md, `train.compare.report`), and next
to it a folder with metrics.json (the `planar-pose evaluate` layout, via
`train.network.report.write_metrics`), detection_metrics.json, the summary plots
(`train.compare.plots`) and, in its `details` folder, the per-cell report and plots.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from tqdm import tqdm

from service.core.dataset import LoadedDataset
from train.compare.baseline import dataset_cameras
from train.compare.detection import detection_variants
from train.compare.peers import (
    PEER_CHOICES,
    default_peers,
    peer_name,
    run_peer_on,
    run_reference,
)
from train.compare.plots import plot_accuracy, plot_times
from train.compare.report import GIVEN_FX, ReportContext, comparison_markdown
from train.compare.sets import (
    describe,
    encode_png,
    load_part,
    photo_set,
    profile_of,
    same_object,
    stored_photos,
)
from train.markdown import pct
from train.network.evaluate import evaluate_predictor, model_predictor


class ModelEntry(NamedTuple):
    """A compared network: its ONNX file, predict function, input size (W, H), model card,
    and whether it is given each image's focal length (the `GIVEN_FX` variant)."""

    path: Path
    predict: Callable[..., Any]
    size: tuple[int, int]
    card: dict[str, Any]
    given_fx: bool = False


#: {method name: entry}.
Models = dict[str, ModelEntry]
#: {method name: {data set name: metrics}}: the `train.network.report` results layout.
Results = dict[str, dict[str, dict[str, Any]]]


@dataclass
class CompareConfig:
    """What `run_comparison` measures (see the module docstring). `peers`: kinds of
    `train.compare.peers.PEER_CHOICES` (empty: `default_peers(features)`)."""

    models: list[Path]
    datasets: list[Path]
    markdown: Path = Path("docs/comparison.md")
    features: str = "sift"
    split: str = "test"
    photos: Path | None = None
    detection_datasets: list[Path] = field(default_factory=list)
    limit: int = 0
    tune: bool = True
    peers: list[str] = field(default_factory=list)
    resize: bool = False
    given_fx: bool = True

    def peer_kinds(self) -> list[str]:
        """The peers to run, in order, without repeats; ValueError for an unknown one."""
        kinds = list(dict.fromkeys(self.peers or default_peers(self.features)))
        bad = [k for k in kinds if k not in PEER_CHOICES]
        if bad:
            raise ValueError(f"peer must be one of {', '.join(PEER_CHOICES)}, got {bad[0]!r}")
        return kinds


def load_models(paths: list[Path], given_fx: bool = False) -> Models:
    """The ONNX models by name (their card's name, else the file stem), as the service
    answers (`model_predictor`: with the zoom pass where the graph serves it); with
    `given_fx`, each model whose graph takes a focal length also as `<name> + fx`."""
    from service.pipeline import ModelLoadError, PoseModel

    loaded: Models = {}
    for path in paths:
        try:
            model = PoseModel.load(path, intra_op_threads=0)
        except ModelLoadError as exc:
            raise ValueError(str(exc)) from None
        own = model.card.get("name")
        name = own if isinstance(own, str) else path.stem
        size = (int(model.input_size[0]), int(model.input_size[1]))
        loaded[name] = ModelEntry(path, model_predictor(model), size, model.card)
        if given_fx and model.takes_focal:
            loaded[name + GIVEN_FX] = loaded[name]._replace(given_fx=True)
    return loaded


def camera_focal(data: LoadedDataset, width: int) -> np.ndarray:
    """The fx [N] of the camera the chessboard detector is given for each image of `data`
    (labels.csv, else the source's calibration, else the SPEC camera), in pixels of a
    network input `width` pixels wide."""
    cameras = dataset_cameras(data.path, data.column("file"), data.size)
    scale = width / data.size[0]
    return np.array([float(c.K[0, 0]) * scale for c in cameras], np.float32)


def _reference(
    data: LoadedDataset,
    key: str,
    cache: dict[tuple[Any, ...], tuple[str, dict[str, Any]]],
    results: Results,
) -> dict[str, tuple[str, dict[str, Any]]] | None:
    """The chessboard detector on the stored photos behind `data` (computed once per photo
    list), recorded in `results`; None when the photos are not here or it does not apply."""
    photos = stored_photos(data)
    if photos is None:
        return None
    cache_key = tuple(photos.paths)
    if cache_key not in cache:
        measured = run_reference(data, photos, verbose=True)
        if measured is None:
            return None
        name = f"{photos.name}, {len(photos.paths)} of `{key}`"
        cache[cache_key] = (name, measured[0])
        results.setdefault(f"{peer_name('chessboard')}@stored", {})[name] = measured[0]
    return {peer_name("chessboard"): cache[cache_key]}


def measure_dataset(
    folder: Path,
    config: CompareConfig,
    models: Models,
    results: Results,
    cache: dict[tuple[Any, ...], tuple[str, dict[str, Any]]],
) -> dict[str, Any]:
    """Every model and peer on one data set's split: its report row (see train.compare.report);
    the metrics go into `results`."""
    data = load_part(folder, config.split, config.limit)
    if not len(data.labels):
        raise ValueError(f"{folder} has no images in split {config.split!r}")
    desc = describe(folder, data.images)
    key = f"{desc['object']}/{folder.name}"
    row = {"name": key, **desc, "n": len(data.labels), "acc": {}, "ms": {}, "info": {}}
    row["margin"] = {}
    measured: dict[str, dict[str, Any]] = {}
    for name, entry in models.items():
        if (entry.size != desc["size"] and not config.resize) or not same_object(
            entry.card, folder
        ):
            continue
        focal = camera_focal(data, entry.size[0]) if entry.given_fx else None
        with tqdm(total=len(data.labels), desc=f"{name} on {folder.name}") as bar:
            measured[name] = evaluate_predictor(entry.predict, data, bar.update, focal)
    for kind in config.peer_kinds():
        out = run_peer_on(data, kind, config.split, config.tune, config.limit, verbose=True)
        if out is not None:
            measured[peer_name(kind)], row["info"][peer_name(kind)] = out
    for name, m in measured.items():
        results.setdefault(name, {})[key] = m
        row["acc"][name], row["ms"][name] = m["accuracy"], m["ms_per_image"]
        row["margin"][name] = m.get("by_margin")
    row["reference"] = (
        _reference(data, key, cache, results) if "chessboard" in config.peer_kinds() else None
    )
    tqdm.write(
        f"{key}: "
        + ", ".join(f"{n} {pct(a)} ({row['ms'][n]:.2f} ms)" for n, a in row["acc"].items())
    )
    return row


def measure_detections(
    config: CompareConfig, models: Models
) -> dict[str, dict[str, dict[str, Any]]]:
    """Whole / sliding / proposals of every model on --photos and the detection data sets:
    {model: {image subset: {variant: metrics}}} ({} when neither was given)."""
    if config.photos is None and not config.detection_datasets:
        return {}
    z_split = float(profile_of(config.datasets[0], None).geometry.z_split_cm)
    sets: list[tuple[str, list[bytes], np.ndarray, dict[str, np.ndarray]]] = []
    if config.photos is not None:
        photos, labels, splits = photo_set(config.photos, z_split)
        name = f"{config.photos.name} photos"
        subsets = {
            f"{name}, all": np.ones(len(labels), bool),
            f"{name}, test split": np.array(splits) == "test",
        }
        sets.append((name, photos, labels, subsets))
    for folder in config.detection_datasets:
        d = load_part(folder, config.split, config.limit)
        sets.append(
            (
                folder.name,
                encode_png(d.images),
                d.labels,
                {folder.name: np.ones(len(d.labels), bool)},
            )
        )
    detections: dict[str, dict[str, dict[str, Any]]] = {}
    for name, entry in models.items():
        if entry.given_fx:  # the detection variants take no focal length
            continue
        detections[name] = {}
        for set_name, images, labels, masks in sets:
            tqdm.write(f"detection variants: {name} on {set_name}")
            detections[name] |= detection_variants(entry.path, images, labels, masks)
    return detections


def write_outputs(
    config: CompareConfig,
    models: Models,
    rows: list[dict[str, Any]],
    results: Results,
    detections: dict[str, dict[str, dict[str, Any]]],
) -> list[str]:
    """metrics.json, the per-cell details (`write_details`, in out_dir/details),
    detection_metrics.json, the summary plots and the Markdown report; returns the main files
    written."""
    from train.network.report import DETAILS_DIR, write_details, write_metrics

    out_dir = config.markdown.with_suffix("")
    title = "Comparison: CNN vs the classical peers"
    sources = {n: str(e.path) for n, e in models.items()}
    sources |= {r["name"]: str(d) for r, d in zip(rows, config.datasets, strict=True)}
    write_metrics(results, out_dir, title, sources)
    details = write_details(
        results,
        out_dir / DETAILS_DIR,
        title,
        [
            f"Split `{config.split}`. Written by `planar-pose compare`; "
            f"summary in {config.markdown}."
        ],
    )
    if detections:
        (out_dir / "detection_metrics.json").write_text(json.dumps(detections, indent=1) + "\n")
    peers = [p for p in map(peer_name, config.peer_kinds()) if any(p in r["acc"] for r in rows)]
    names = [*models, *peers]
    plot_accuracy(rows, names, out_dir / "plots" / "accuracy_vs_blur.png")
    plot_times(rows, names, out_dir / "plots" / "time_per_image.png")
    ctx = ReportContext(
        config.split,
        config.limit,
        {n: (e.path, e.size, e.card) for n, e in models.items()},
        peers,
        config.markdown.parent,
        out_dir,
        config.resize,
        frozenset(n for n, e in models.items() if e.given_fx),
    )
    config.markdown.parent.mkdir(parents=True, exist_ok=True)
    config.markdown.write_text(comparison_markdown(ctx, rows, detections, details))
    return [str(config.markdown), str(out_dir / "metrics.json"), str(details)]


def run_comparison(config: CompareConfig) -> dict[str, Any]:
    """Measure everything (module docstring), write the reports; return a summary with
    `columns`, `rows` (strings for a console table) and `files` written."""
    if not config.models:
        raise ValueError("give at least one ONNX model")
    if not config.datasets:
        raise ValueError("give at least one data set")
    config.peer_kinds()  # unknown peers fail before anything is measured
    models = load_models(config.models, config.given_fx)
    results: Results = {name: {} for name in models}
    rows: list[dict[str, Any]] = []
    cache: dict[tuple[Any, ...], tuple[str, dict[str, Any]]] = {}
    for folder in config.datasets:
        row = measure_dataset(folder, config, models, results, cache)
        if any(r["name"] == row["name"] for r in rows):
            raise ValueError(f"two data sets would be named {row['name']}")
        rows.append(row)
    detections = measure_detections(config, models)
    files = write_outputs(config, models, rows, results, detections)
    names = [*models, *(n for n in results if n not in models and "@" not in n)]
    table_rows = [
        [r["name"]]
        + [
            f"{pct(r['acc'][n], unit=False)} ({r['ms'][n]:.2f})" if n in r["acc"] else ""
            for n in names
        ]
        for r in rows
    ]
    return {"columns": names, "rows": table_rows, "files": files}
