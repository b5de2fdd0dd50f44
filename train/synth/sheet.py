"""Contact sheet of a data set: one row of sample images per class, labelled in words."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from service.core.dataset import load_dataset
from service.core.regions import NUM_CLASSES, region_of_class

LABEL_WIDTH = 190  # px of the text column
GAP = 2  # px between tiles


def contact_sheet(
    dataset: Path,
    out: Path,
    per_class: int = 8,
    scale: int = 2,
    split: str | None = None,
    seed: int = 0,
) -> np.ndarray:
    """Draw `per_class` random images of each class 0..8 (rows) of `dataset`, magnified by
    `scale` (nearest neighbour, to see the pixels), with the class id and its region in words
    (`service.core.regions.region_of_class`); write it to `out` (PNG) and return it (RGB uint8).

    A class with fewer images leaves its remaining tiles light grey.
    """
    data = load_dataset(dataset, split=split)
    w, h = data.size
    tw, th = w * scale, h * scale
    rows, cols = NUM_CLASSES, per_class
    sheet = np.full(
        (rows * (th + GAP) + GAP, LABEL_WIDTH + cols * (tw + GAP) + GAP, 3), 255, np.uint8
    )
    rng = np.random.default_rng(seed)
    for k in range(rows):
        y = GAP + k * (th + GAP)
        region = region_of_class(k)
        count = int(np.sum(data.labels == k))
        lines = [f"class {k} ({count})", *region["label"].split(", ", 1)]
        for j, text in enumerate(lines):
            cv2.putText(
                sheet,
                text,
                (8, y + 22 + 22 * j),
                cv2.FONT_HERSHEY_SIMPLEX,
                0.55,
                (0, 0, 0),
                1,
                cv2.LINE_AA,
            )
        for c in range(cols):  # empty tiles stay light grey
            x = LABEL_WIDTH + GAP + c * (tw + GAP)
            sheet[y : y + th, x : x + tw] = 225
        index = np.flatnonzero(data.labels == k)
        picked = rng.choice(index, size=min(cols, len(index)), replace=False)
        for c, i in enumerate(sorted(picked)):
            x = LABEL_WIDTH + GAP + c * (tw + GAP)
            sheet[y : y + th, x : x + tw] = cv2.resize(
                data.images[i], (tw, th), interpolation=cv2.INTER_NEAREST
            )
    out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR)):
        raise OSError(f"could not write the contact sheet to {out} (use a .png name)")
    return sheet
