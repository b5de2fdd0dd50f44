"""Evaluation (SPEC section 10): classifier predictions on a data set and the metrics on them.

`compute_metrics` is the one place where accuracy, per-class precision / recall / F-measure and
the confusion matrix are computed; `train.network.report.write_report` turns its results into
metrics.json, Markdown and plots. Both are shared with the feature baseline.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from service.core.dataset import LoadedDataset
from service.core.preprocess import to_network_input
from service.core.regions import NUM_CLASSES, is_far, quadrant_of_class

if TYPE_CHECKING:
    from service.pipeline import PoseModel

#: A classifier: RGB uint8 images [N, H, W, 3] at the network's size and their pixel aspect
#: [N] (`service.core.preprocess.NetworkFrame.pixel_aspect`: 1 unless a photo was squashed) ->
#: probabilities float32 [N, 9]. A predictor of a graph that takes the camera's focal length
#: (`model_predictor`) also takes `focal` [N] (px of the input's width, 0: unknown).
Predictor = Callable[..., np.ndarray]


def _ratio(num: float, den: float) -> float | None:
    """num / den, or None when den is 0 (undefined, written as null in JSON)."""
    return None if den == 0 else float(num) / float(den)


def confusion_matrix(y_true: np.ndarray, y_pred: np.ndarray) -> np.ndarray:
    """Confusion matrix int64 [9, 9]: rows are ground-truth classes, columns predictions."""
    y_true = np.asarray(y_true, dtype=np.int64).ravel()
    y_pred = np.asarray(y_pred, dtype=np.int64).ravel()
    if y_true.shape != y_pred.shape:
        raise ValueError(f"{y_true.size} labels but {y_pred.size} predictions")
    for name, y in (("labels", y_true), ("predictions", y_pred)):
        if y.size and (y.min() < 0 or y.max() >= NUM_CLASSES):
            raise ValueError(f"{name} must be class ids in 0..{NUM_CLASSES - 1}")
    flat = np.bincount(y_true * NUM_CLASSES + y_pred, minlength=NUM_CLASSES * NUM_CLASSES)
    return flat.reshape(NUM_CLASSES, NUM_CLASSES)


#: Bands (cm) of the camera centre's distance from the nearest region boundary (`by_margin`).
MARGIN_BANDS_CM: tuple[tuple[float, float], ...] = ((0, 2), (2, 5), (5, 10), (10, math.inf))


def compute_metrics(
    y_true: np.ndarray,
    y_pred: np.ndarray,
    ms_per_image: float,
    margin_cm: np.ndarray | None = None,
    cut: np.ndarray | None = None,
) -> dict[str, Any]:
    """SPEC 10 metrics of predicted classes `y_pred` against `y_true` (both int [N], 0..8).

    Returns a JSON-ready dict: `count`, `accuracy` (global, in [0, 1]), `per_class_accuracy`,
    `precision`, `recall`, `f1` (9 values each), `confusion` (9x9 counts, rows = ground
    truth), `ms_per_image`, and `regions`: what the predictions on images that show the
    object (classes 1-8) get right (`region_breakdown`). Per-class accuracy is the share of a
    class's images classified correctly (the confusion diagonal over its row, like recall). A
    value whose denominator is zero is None: precision of a class never predicted, recall of
    a class absent from the ground truth, F1 of a class absent from both.

    With `margin_cm` (float [N], `LoadedDataset.boundary_margin_cm`: the camera centre's
    distance from the nearest region boundary, nan for class 0), `by_margin` lists per band
    of `MARGIN_BANDS_CM` the object images in it and the share classified right: how close
    to a boundary the errors are. With `cut` (float [N], `LoadedDataset.board_cut`: 1 where
    the frame cuts the object, 0 where it is whole in view, nan otherwise), `by_framing` has
    the `whole` and `cut` object images, each as `count` and `accuracy`.
    """
    cm = confusion_matrix(y_true, y_pred)
    total = int(cm.sum())
    if total == 0:
        raise ValueError("no samples to evaluate")
    diag = np.diag(cm)
    rows, cols = cm.sum(axis=1), cm.sum(axis=0)
    recall = [_ratio(diag[k], rows[k]) for k in range(NUM_CLASSES)]
    precision = [_ratio(diag[k], cols[k]) for k in range(NUM_CLASSES)]
    # F1 = 2 TP / (2 TP + FP + FN): 0 when the class is missed or only wrongly predicted.
    f1 = [_ratio(2 * diag[k], rows[k] + cols[k]) for k in range(NUM_CLASSES)]
    metrics: dict[str, Any] = {
        "count": total,
        "accuracy": float(diag.sum()) / total,
        "per_class_accuracy": recall,
        "precision": precision,
        "recall": recall,
        "f1": f1,
        "confusion": cm.tolist(),
        "ms_per_image": float(ms_per_image),
        "regions": region_breakdown(cm),
    }
    if margin_cm is not None:
        metrics["by_margin"] = margin_breakdown(y_true, y_pred, margin_cm)
    if cut is not None:
        metrics["by_framing"] = framing_breakdown(y_true, y_pred, cut)
    return metrics


def framing_breakdown(
    y_true: np.ndarray, y_pred: np.ndarray, cut: np.ndarray
) -> dict[str, dict[str, float | int | None]]:
    """`whole` and `cut` (`compute_metrics`): the object images the frame shows whole or cuts
    (`count`) and the share of them classified right (`accuracy`, None when there are none)."""
    return {
        name: _share_right(y_true, y_pred, cut == value)
        for name, value in (("whole", 0), ("cut", 1))
    }


def _share_right(
    y_true: np.ndarray, y_pred: np.ndarray, these: np.ndarray
) -> dict[str, float | int | None]:
    """`count` of the images `these` (bool [N]) and the share of them classified right
    (`accuracy`, None when there are none)."""
    right = float((y_true[these] == y_pred[these]).sum())
    return {"count": int(these.sum()), "accuracy": _ratio(right, these.sum())}


def margin_breakdown(
    y_true: np.ndarray, y_pred: np.ndarray, margin_cm: np.ndarray
) -> list[dict[str, float | int | None]]:
    """Per band [lo, hi) cm of `MARGIN_BANDS_CM`: `lo_cm`, `hi_cm` (None for no bound), the
    object images whose camera centre is that far from a region boundary (`count`) and the
    share of them classified right (`accuracy`, None when the band is empty)."""
    bands = []
    for lo, hi in MARGIN_BANDS_CM:
        inside = (margin_cm >= lo) & (margin_cm < hi)
        bound = {"lo_cm": lo, "hi_cm": None if math.isinf(hi) else hi}
        bands.append(bound | _share_right(y_true, y_pred, inside))
    return bands


def source_breakdown(
    y_true: np.ndarray, y_pred: np.ndarray, rows: list[dict[str, str]]
) -> dict[str, dict[str, float | int | None]]:
    """Per source (camera; the labels.csv `source` column of a real set): photos (`count`),
    class `accuracy`, the `region_breakdown` shares `detected`, `side` and `distance`, and
    `focal_scale`, the median fx / width of its calibrated photos over the SPEC camera's
    (None without a calibration): the depth of a frontal board follows from it, which one
    photo cannot tell (docs/decisions.md). {} for a set without sources."""
    sources = np.array([row.get("source", "") for row in rows])
    out: dict[str, dict[str, float | int | None]] = {}
    for name in sorted(set(sources) - {""}):
        mine = sources == name
        regions = region_breakdown(confusion_matrix(y_true[mine], y_pred[mine]))
        mine_rows = [row for row, m in zip(rows, mine, strict=True) if m]
        focal = [float(row["focal_scale"]) for row in mine_rows if row.get("focal_scale")]
        out[str(name)] = {
            "count": int(mine.sum()),
            "accuracy": round(float(np.mean(y_true[mine] == y_pred[mine])), 4),
            **{k: regions[k] for k in ("detected", "side", "distance")},
            "focal_scale": round(float(np.median(focal)), 3) if focal else None,
        }
    return out


def region_breakdown(cm: np.ndarray) -> dict[str, float | None]:
    """Shares of the object images (true class 1-8) of a 9x9 confusion matrix whose prediction

    * `detected`: is an object class (1-8);
    * `side`: has the right x/y quadrant (distance ignored);
    * `distance`: has the right near / far half;
    * `opposite_side`: has the diagonally opposite quadrant (a half turn of the object).

    None when no image shows the object.
    """
    classes = np.arange(NUM_CLASSES)
    quadrant, far = quadrant_of_class(classes), is_far(classes)
    obj = cm[1:, 1:]  # object images predicted as object classes
    q_true, q_pred = quadrant[1:, None], quadrant[None, 1:]
    total = cm[1:].sum()
    return {
        "detected": _ratio(obj.sum(), total),
        "side": _ratio(obj[q_true == q_pred].sum(), total),
        "distance": _ratio(obj[far[1:, None] == far[None, 1:]].sum(), total),
        "opposite_side": _ratio(obj[(q_pred - q_true) % 4 == 2].sum(), total),
    }


def network_batch(images: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """RGB uint8 [N, H0, W0, 3] -> float32 [N, 3, H, W] in [0, 1] via the service preprocessing."""
    return np.stack([to_network_input(img, size) for img in images])


def onnx_predictor(
    path: Path, threads: int = 0, zoom: bool = True
) -> tuple[Predictor, tuple[int, int], dict[str, Any]]:
    """Load an exported model as the service does (`service.pipeline.PoseModel`, onnxruntime)
    -> (predictor, input size (W, H), model card). `threads` 0 lets onnxruntime choose;
    `zoom`: with the service's zoom pass (`service.pipeline.zoom`) where the graph serves it."""
    from service.pipeline import ModelLoadError, PoseModel

    try:
        model = PoseModel.load(path, intra_op_threads=threads)
    except ModelLoadError as exc:
        raise ValueError(str(exc)) from None
    return model_predictor(model, zoom), model.input_size, model.card


def model_predictor(model: PoseModel, zoom: bool = True, search: bool = True) -> Predictor:
    """A `Predictor` on a `service.pipeline.PoseModel`, as the service's whole mode answers:
    the service's preprocessing, then the graph (with the zoom pass if `zoom`, its search of
    frames with no board found if `search`: POSE_ZOOM, POSE_ZOOM_SEARCH; its tiles cut from
    images of at least twice the input size, `service.pipeline.detail_of`)."""
    from service.pipeline import detail_of, zoomed

    def predict(
        images: np.ndarray, pixel_aspect: np.ndarray, focal: np.ndarray | None = None
    ) -> np.ndarray:
        batch = network_batch(images, model.input_size)
        if zoom:
            detail = [detail_of(image, model.input_size) for image in images]
            return zoomed(model, batch, pixel_aspect, search, focal, detail).probabilities
        return model.run(batch, pixel_aspect, focal=focal).probabilities

    return predict


def checkpoint_predictor(path: Path) -> tuple[Predictor, tuple[int, int], dict[str, Any]]:
    """Load a training checkpoint with PyTorch -> (predictor, input size (W, H), its config)."""
    import torch

    from train.network.fit import load_network
    from train.network.model import log_probabilities

    net, checkpoint = load_network(path)
    net.eval()

    def predict(images: np.ndarray, pixel_aspect: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            x = torch.from_numpy(network_batch(images, net.size))
            aspect = torch.from_numpy(np.asarray(pixel_aspect, np.float32))
            return torch.exp(log_probabilities(net, x, aspect)).numpy()

    return predict, net.size, checkpoint.get("config", {})


def load_predictor(path: Path) -> tuple[Predictor, tuple[int, int], dict[str, Any]]:
    """A model file (.onnx, or a .pt training checkpoint) -> (predictor, size (W, H), info)."""
    if not path.is_file():
        raise FileNotFoundError(f"model not found: {path}")
    if path.suffix == ".onnx":
        return onnx_predictor(path)
    if path.suffix == ".pt":
        return checkpoint_predictor(path)
    raise ValueError(f"{path}: a model is an .onnx file or a .pt training checkpoint")


def predict_all(
    predict: Predictor,
    images: np.ndarray,
    pixel_aspect: np.ndarray | None = None,
    batch: int = 64,
    progress: Callable[..., Any] | None = None,
    focal: np.ndarray | None = None,
) -> tuple[np.ndarray, float]:
    """Run `predict` over images [N, H, W, 3] and their pixel aspect [N] (None: all 1) in
    batches -> (probabilities [N, 9], ms / image). `focal` [N]: the cameras' focal lengths
    (px of the network input's width) for a predictor that takes them (None: not given).

    The time covers preprocessing and inference, measured with a wall clock.
    """
    aspect = np.ones(len(images), np.float32) if pixel_aspect is None else pixel_aspect
    out = []
    start = time.perf_counter()
    for i in range(0, len(images), batch):
        given = {} if focal is None else {"focal": focal[i : i + batch]}
        out.append(predict(images[i : i + batch], aspect[i : i + batch], **given))
        if progress is not None:
            progress(min(batch, len(images) - i))
    elapsed = time.perf_counter() - start
    probs = np.concatenate(out) if out else np.zeros((0, NUM_CLASSES), np.float32)
    return probs, 1000.0 * elapsed / max(len(images), 1)


def evaluate_predictor(
    predict: Predictor,
    data: LoadedDataset,
    progress: Callable[..., Any] | None = None,
    focal: np.ndarray | None = None,
) -> dict[str, Any]:
    """Metrics (see `compute_metrics`) of a predictor on a loaded data set (or split): its
    images, labels, pixel aspect and the camera centres' margins; `focal` as `predict_all`.
    A real set (photos with a `source`) also gets `by_source` (`source_breakdown`)."""
    probs, ms = predict_all(
        predict, data.images, data.pixel_aspect(), progress=progress, focal=focal
    )
    predicted = probs.argmax(axis=1)
    metrics = compute_metrics(
        data.labels, predicted, ms, data.boundary_margin_cm(), data.board_cut()
    )
    if by_source := source_breakdown(data.labels, predicted, data.rows):
        metrics["by_source"] = by_source
    return metrics
