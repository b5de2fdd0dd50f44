"""Detection variants (SPEC section 9) through the service's own `service.pipeline.Predictor`
(image bytes in, like an HTTP call): whole image, sliding windows, and object proposals
(`service.pipeline.propose_boxes` as the predictor's box generator) on the service's working
copy and on a 4x larger one."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Literal

import numpy as np

from train.network.evaluate import compute_metrics

#: Proposals per image in the objectness mode; about the sliding window count at 1.5x.
PROPOSALS_MAX = 20
#: Working copy scales (network inputs per largest window) for the objectness mode.
PROPOSAL_RESOLUTIONS = (1.5, 4.0)


def detection_variants(
    model_path: Path,
    images: list[bytes],
    labels: np.ndarray,
    subsets: dict[str, np.ndarray] | None = None,
    chunk: int = 16,
) -> dict[str, dict[str, dict[str, Any]]]:
    """Metrics of whole / sliding / proposals modes through `service.pipeline.Predictor`.

    Returns {subset name: {variant: metrics}}; `subsets` maps names to boolean masks [N]
    (default: one subset "all"). Images go in chunks of `chunk` (the service's default
    per-request limit); ms per image is the wall clock of the predictor calls over all images
    (decode + boxes + batched onnxruntime + decision).
    """
    from service.pipeline import PoseModel, Predictor, Settings, propose_boxes

    model = PoseModel.load(model_path)
    aspect = model.input_size[0] / model.input_size[1]

    def proposals(work: np.ndarray) -> np.ndarray:
        return propose_boxes(work, aspect, PROPOSALS_MAX)

    variants: dict[str, tuple[Predictor, Literal["whole", "sliding"]]] = {
        "whole": (Predictor(model, Settings()), "whole"),
        "sliding": (Predictor(model, Settings()), "sliding"),
    }
    for res in PROPOSAL_RESOLUTIONS:
        predictor = Predictor(model, Settings(sliding_resolution=res), boxes=proposals)
        variants[f"proposals@{res:g}x"] = (predictor, "sliding")
    subsets = subsets or {"all": np.ones(len(labels), bool)}
    results: dict[str, dict[str, dict[str, Any]]] = {name: {} for name in subsets}
    for variant, (predictor, mode) in variants.items():
        predicted = []
        start = time.perf_counter()
        for i in range(0, len(images), chunk):
            batch = [(None, b) for b in images[i : i + chunk]]
            predicted += [r.class_id for r in predictor.predict(batch, mode).results]
        ms = 1000.0 * (time.perf_counter() - start) / max(len(images), 1)
        for name, mask in subsets.items():
            if mask.any():
                results[name][variant] = compute_metrics(
                    labels[mask], np.array(predicted)[mask], ms
                )
    return {name: res for name, res in results.items() if res}
