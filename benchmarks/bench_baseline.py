"""Time per image of the feature baseline vs the CNN, and of the box generators, in one run.

On the 26 real photographs (train/assets/real/chessboard-stereo) resized to each network size:

* the CNN: an ONNX model through `train.network.evaluate.model_predictor` (the service's
  preprocessing + onnxruntime, and its zoom pass where the model serves it), batch 64 and
  batch 1; and with the zoom pass without its search and off, on these photos and on photos
  without the board (the negatives of one train source of the corpus, where the search looks
  at every tile);
* the feature baseline (`train.compare.baseline`, SIFT and ORB, images enlarged to 320 px wide);
* the chessboard detector peer (`train.compare.chessboard_peer`: the image enlarged 4x,
  `findChessboardCornersSB`, fallback `findChessboardCorners`, parity, IPPE PnP) and how many
  of the photos it answers right;
* box generation on the 640x480 photos: the service's sliding-window grid vs
  `service.pipeline.proposals.propose_boxes`.

Prints ms / image and the ratios (the thesis: baseline about 10x slower than the network).

    .venv/bin/python benchmarks/bench_baseline.py [--model MODEL.onnx] [--repeat 3]
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import numpy as np

from service.core.paths import DEFAULT_MODEL
from service.core.preprocess import resize_rgb
from service.core.profile import load_profile
from service.core.regions import pose_class
from service.pipeline.model import PoseModel
from service.pipeline.proposals import propose_boxes
from service.pipeline.sliding import SlidingWindows
from train.compare.baseline import BaselineConfig, FeatureBaseline
from train.compare.chessboard_peer import ChessboardPeer
from train.network.evaluate import model_predictor, predict_all
from train.real.calibration import Calibration
from train.real.label import chessboard_pattern
from train.real.realset import read_rgb

ASSETS = Path(__file__).resolve().parent.parent / "train" / "assets" / "real"
REAL = ASSETS / "chessboard-stereo"
NEGATIVES = ASSETS / "corpus" / "negatives" / "danielgatis__rembg" / "images"  # a train source


def best_of(repeat: int, run) -> float:  # noqa: ANN001
    """Smallest wall-clock ms / image of `repeat` runs of `run()` (which returns ms / image)."""
    return min(run() for _ in range(repeat))


def chessboard_peer(profile, images, cameras, repeat: int) -> tuple[float, int]:  # noqa: ANN001
    """Best ms / image of the chessboard peer over `repeat` runs, and how many it got right."""
    z_split = float(profile.geometry.z_split_cm)
    peer = ChessboardPeer(chessboard_pattern(profile), z_split)
    with (REAL / "labels.csv").open(newline="") as fh:
        rows = {r["file"]: r for r in csv.DictReader(fh)}
    truth = [
        int(pose_class(np.array([float(rows[f][k]) for k in ("cam_x", "cam_y", "cam_z")]), z_split))
        for f in sorted(rows)
    ]
    labels: list[int] = []

    def run() -> float:
        labels.clear()
        start = time.perf_counter()
        for image, camera in zip(images, cameras, strict=True):
            labels.append(peer.predict(image, camera).label)
        return 1000 * (time.perf_counter() - start) / len(images)

    ms = best_of(repeat, run)
    return ms, int(np.sum(np.array(labels) == np.array(truth)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, default=DEFAULT_MODEL)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()

    files = sorted(p for p in REAL.glob("*.jpg"))
    photos = [read_rgb(p) for p in files]
    model = PoseModel.load(args.model, intra_op_threads=1)  # as onnx_predictor loads it
    size, predict = model.input_size, model_predictor(model)
    images = np.stack([resize_rgb(p, size) for p in photos])
    profile = load_profile("chessboard")
    calibration = Calibration.load(REAL / "calibration.json")
    cameras = [calibration.for_image(f.name, size) for f in files]

    cnn64 = best_of(args.repeat, lambda: predict_all(predict, images, batch=64)[1])
    cnn1 = best_of(args.repeat, lambda: predict_all(predict, images, batch=1)[1])
    print(f"{len(images)} real photos at {size[0]}x{size[1]}, best of {args.repeat} runs")
    print(f"CNN {args.model.name}: {cnn64:.3f} ms / image (batch 64), {cnn1:.3f} (batch 1)")
    whole, unsearched = model_predictor(model, zoom=False), model_predictor(model, search=False)
    negatives = np.stack([resize_rgb(read_rgb(p), size) for p in sorted(NEGATIVES.glob("*"))])
    sets = (("these photos", images), (f"{len(negatives)} photos without the board", negatives))
    for name, batch in sets:
        zoom_ms, small_ms, whole_ms = (
            best_of(args.repeat, lambda b=batch, f=f: predict_all(f, b, batch=64)[1])
            for f in (predict, unsearched, whole)
        )
        print(
            f"zoom pass on {name}: {zoom_ms:.3f} ms / image, {small_ms:.3f} without its search "
            f"(POSE_ZOOM_SEARCH=false), {whole_ms:.3f} without the pass = "
            f"{zoom_ms / whole_ms:.1f}x / {small_ms / whole_ms:.1f}x (batch 64)"
        )
    for features in ("sift", "orb"):
        baseline = FeatureBaseline(
            profile.texture_rgb(), profile.width_cm, profile.height_cm,
            profile.geometry.z_split_cm, BaselineConfig(features=features),
        )  # fmt: skip

        def run(b: FeatureBaseline = baseline) -> float:
            start = time.perf_counter()
            for image, camera in zip(images, cameras, strict=True):
                b.predict(image, camera)
            return 1000 * (time.perf_counter() - start) / len(images)

        ms = best_of(args.repeat, run)
        print(
            f"baseline {features}: {ms:.2f} ms / image = {ms / cnn64:.1f}x the CNN (batch 64), "
            f"{ms / cnn1:.1f}x (batch 1)"
        )

    peer_ms, right = chessboard_peer(profile, images, cameras, args.repeat)
    print(
        f"chessboard detector (4x): {peer_ms:.2f} ms / image = {peer_ms / cnn64:.1f}x the CNN "
        f"(batch 64), {peer_ms / cnn1:.1f}x (batch 1); right on {right}/{len(images)}"
    )

    aspect = size[0] / size[1]
    grid = SlidingWindows(aspect=aspect, scales=(1.0, 0.8, 0.6), stride=20, max_windows=256)

    def boxes_ms(generate) -> float:  # noqa: ANN001
        start = time.perf_counter()
        for p in photos:
            generate(p)
        return 1000 * (time.perf_counter() - start) / len(photos)

    def proposals(p: np.ndarray) -> np.ndarray:
        return propose_boxes(p, aspect, 20)

    counts = [np.mean([len(g(p)) for p in photos]) for g in (grid, proposals)]
    sliding = best_of(args.repeat, lambda: boxes_ms(grid))
    proposed = best_of(args.repeat, lambda: boxes_ms(proposals))
    print(
        f"box generation on 640x480: sliding grid {sliding:.3f} ms ({counts[0]:.0f} boxes), "
        f"proposals {proposed:.2f} ms ({counts[1]:.0f} boxes) = {proposed / sliding:.0f}x"
    )


if __name__ == "__main__":
    main()
