"""Labelled images answered through the service's own path (`service.pipeline.Predictor`, the
code behind `/v1/predict`), with the anatomy of the answers: class right, class 0 right,
among the images whose object was found near/far and x/y side right, found, refined
(`corners_source`), the corners' error against the labels and the time per image.

Used by `scripts/refine_accuracy.py` and `scripts/any_eval.py` (`train.compare.anyobject`).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from service.core.dataset import load_dataset
from service.core.regions import is_far, quadrant_of_class
from service.pipeline import KnownFocal, Predictor


@dataclass(frozen=True)
class Photo:
    """One image: its encoded bytes, class, labelled corners [4, 2] px (None: class 0) and
    its calibration (None: not known)."""

    data: bytes
    label: int
    corners: np.ndarray | None
    camera: KnownFocal | None


def dataset_photos(path: Path) -> list[Photo]:
    """The images of a rendered set (`service.core.dataset`) as PNG photos, no camera."""
    data = load_dataset(path)
    corners = data.corners()
    photos = []
    for i, (rgb, label) in enumerate(zip(data.images, data.labels, strict=True)):
        ok, png = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        if not ok:
            raise ValueError(f"{path}: image {i} cannot be encoded")
        photos.append(Photo(png.tobytes(), int(label), corners[i] if label else None, None))
    return photos


@dataclass
class Anatomy:
    """Counts over one set's answers (module doc); shares are None where nothing counts."""

    images: int = 0
    right: int = 0
    absent: int = 0
    absent_right: int = 0
    present: int = 0
    found: int = 0
    depth_right: int = 0
    side_right: int = 0
    refined: int = 0
    corner_px: list[float] = field(default_factory=list)
    ms: list[float] = field(default_factory=list)

    @staticmethod
    def share(n: int, d: int) -> float | None:
        return n / d if d else None

    def as_dict(self) -> dict[str, float | None]:
        """accuracy, class0, near_far, side, found, refined (shares of 1), corner_px and ms
        (medians)."""
        return {
            "accuracy": self.share(self.right, self.images),
            "class0": self.share(self.absent_right, self.absent),
            "near_far": self.share(self.depth_right, self.found),
            "side": self.share(self.side_right, self.found),
            "found": self.share(self.found, self.present),
            "refined": self.share(self.refined, self.found),
            "corner_px": float(np.median(self.corner_px)) if self.corner_px else None,
            "ms": float(np.median(self.ms)) if self.ms else None,
        }


def answer_all(
    predictor: Predictor, photos: Sequence[Photo], known: Sequence[KnownFocal | None]
) -> Anatomy:
    """Each photo answered alone (`whole` mode) with its camera from `known` -> the counts."""
    out = Anatomy()
    for photo, camera in zip(photos, known, strict=True):
        t0 = time.perf_counter()
        result = predictor.predict([(None, photo.data)], "whole", camera).results[0]
        out.ms.append(1000 * (time.perf_counter() - t0))
        out.images += 1
        out.right += result.class_id == photo.label
        out.absent += photo.label == 0
        out.absent_right += photo.label == 0 and result.class_id == 0
        out.present += photo.label > 0
        if result.class_id and photo.label:
            out.found += 1
            out.depth_right += is_far(result.class_id) == is_far(photo.label)
            out.side_right += quadrant_of_class(result.class_id) == quadrant_of_class(photo.label)
            out.refined += result.corners_source == "refined"
        if result.corners is not None and photo.corners is not None:
            error = np.linalg.norm(np.array(result.corners) - photo.corners, axis=1).mean()
            out.corner_px.append(float(error))
    return out
