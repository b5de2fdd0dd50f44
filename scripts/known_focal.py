"""What a known focal length gives: class accuracy on the real sets with and without `fx`.

Each photo of the corpus's real-s2-b0..3 sets (val and test sources) is sent through the
service's own path (`service.pipeline.predictor.Predictor`, whole mode, the settings' defaults) once
without `fx` (the pose estimates the focal length) and once with the photo's calibrated fx
(labels.csv `focal_scale`, x the SPEC camera's; photos without a calibration get none).
Writes a markdown page (default docs/known_focal.md) with the date and the machine.

    python scripts/known_focal.py models/chessboard-corners-160x120.onnx runs/default/data
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

from service.core.dataset import DatasetError, LoadedDataset, load_dataset
from service.core.inputs import spec_fx
from service.core.paths import REPO_ROOT
from service.pipeline.focal import KnownFocal
from service.pipeline.model import ModelLoadError, PoseModel
from service.pipeline.predictor import Predictor
from service.settings import Settings
from train.markdown import table, written_by

SPLITS = ("val", "test")


def photo_focal(data: LoadedDataset) -> list[float | None]:
    """Each photo's calibrated fx in pixels of its image in the set (None: no calibration)."""
    width = data.manifest["size"][0]
    scale = spec_fx(width)
    return [float(r["focal_scale"]) * scale if r.get("focal_scale") else None for r in data.rows]


def accuracies(predictor: Predictor, folder: Path, split: str) -> tuple[float, float, int]:
    """(accuracy % without fx, with each photo's fx, photos with a calibration) of a split."""
    data = load_dataset(folder, split=split)
    files = [folder / r["file"] for r in data.rows]
    focal = photo_focal(data)
    right = np.zeros((2, len(files)), bool)
    for i, (path, fx) in enumerate(zip(files, focal, strict=True)):
        image = [(path.name, path.read_bytes())]
        for j, given in enumerate((None, fx)):
            known = None if given is None else KnownFocal(given, "query")
            result = predictor.predict(image, "whole", known).results[0]
            right[j, i] = result.class_id == data.labels[i]
    return 100 * right[0].mean(), 100 * right[1].mean(), sum(f is not None for f in focal)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("model", type=Path, help="an exported corner model (.onnx)")
    parser.add_argument("data", type=Path, help="the folder of the real-s2-b0..3 data sets")
    parser.add_argument("--out", type=Path, default=REPO_ROOT / "docs/known_focal.md")
    args = parser.parse_args()
    try:
        model = PoseModel.load(args.model, intra_op_threads=os.cpu_count() or 1)
    except ModelLoadError as exc:
        sys.exit(f"error: {exc}")
    if not model.takes_focal:
        sys.exit(f"error: {args.model} has no `focal` input (export it again, --regraph)")
    predictor = Predictor(model, Settings())
    rows = []
    try:
        for split in SPLITS:
            found = [accuracies(predictor, args.data / f"real-s2-b{b}", split) for b in range(4)]
            for label, k in (("estimated (no fx)", 0), ("the photo's calibrated fx", 1)):
                cells = " / ".join(f"{a[k]:.1f}" for a in found)
                rows.append([split, label, f"{found[0][2]}", cells])
    except DatasetError as exc:
        sys.exit(f"error: {exc} (run scripts/train_default.sh or `planar-pose corpus sets`)")
    lines = [
        "# A known focal length: class accuracy on the real photos with and without `fx`",
        "",
        written_by(f"python scripts/known_focal.py {args.model} {args.data}")
        + f" Model: {model.name} {model.card.get('version', '')}. Each photo through the "
        "service's path (`/v1/predict?fx=...`, whole mode, default settings); the test "
        "sources are reported, never used to choose anything (docs/service.md, `fx`).",
        "",
        "## Class accuracy (%) at blur 0 / 1 / 2 / 3",
        "",
        *table(["split", "focal length", "calibrated photos", "accuracy"], rows),
        "",
    ]
    args.out.write_text("\n".join(lines), encoding="utf-8")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
