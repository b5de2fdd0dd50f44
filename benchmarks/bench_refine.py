"""What the refinement at the photo's resolution costs, measured in one run: ms per image
through the service's whole mode (`service.predictor.Predictor`, one onnxruntime thread, as
one worker runs it) with the refinement off and on, per corner model, on

* a 1280x720 JPEG of the model's object (a render of its profile by the project's renderer,
  the camera drawn as the data sets draw it, nothing known of it; the lens is fitted), and
  the same with its camera registered (the lens known: no fit);
* a 1280x720 JPEG without the object (a background photo), and every shipped background
  photo of 320 px or more at 1280x720 (the time of all of them): the refinement runs only
  where the network hesitates (its second opinion on "absent", `RESCUE_FROM_P`).

The issue's budget: a board photo at most 1.5x the time without the refinement, a photo
without the object no more. Each time is the best of `--repeat` rounds of `--seconds`, the
refinement off and on called in turn within each round (the same load and clock for both).

Streams (`Predictor.stream_frame` as `WS /v1/stream` runs it: tracked frames, the network's
every 10th frame keeping the track where it agrees) against the network on every frame: ms
per frame and frames/s per core on still sequences (`STILL_SEQUENCES` of `STILL_FRAMES` frames
of the 1280x720 ChArUco render, fresh sensor noise of 2 grey levels per frame) and the spread
of their `camera_cm` (RMS distance from each sequence's mean, pooled over the sequences, cm);
and class right on a video-like sequence (the ChArUco val source's frames in order, 6
frames/s, its camera registered). A tracked frame's alignment hardly moves from the frame
before's corners on a still board, so a tracked sequence's spread is that of the few answers
the network gave it: 32 sequences, so that the spread is pinned (before the network's frames
kept the track, 8 sequences gave 0.0121 cm against the network's 0.0105, 32 gave 0.0099
against 0.0098).

    .venv/bin/python benchmarks/bench_refine.py [--seconds 2] [--repeat 3] [--write-docs]
"""

from __future__ import annotations

import argparse
import csv
import datetime as dt
import math
import os
import platform
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
from docs_section import write_section

from service.core.dataset import camera_of_row
from service.core.geometry import intrinsics
from service.core.profile import load_profile
from service.pipeline.focal import KnownFocal
from service.pipeline.model import PoseModel
from service.pipeline.predictor import Predictor, Track
from service.pipeline.results import ImageResult
from service.settings import Settings
from train.markdown import table
from train.synth.background import BackgroundPool, shipped_backgrounds
from train.synth.generate import DatasetSpec, plan_dataset
from train.synth.render import Renderer

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs" / "benchmarks.md"
NO_OBJECT = ROOT / "train/assets/backgrounds/photos/camera.jpg"
VIDEO = ROOT / "train/assets/real/charuco/boards/mprib__caliscope__4-cam-recording-cam-0"
SIZE = (1280, 720)
MODELS = {"chessboard": "chessboard-corners-160x120", "charuco": "charuco-corners-160x120",
          "book": "book-corners-160x120"}  # fmt: skip
BUDGET_OBJECT, BUDGET_EMPTY = 1.5, 1.0
STILL_SEQUENCES, STILL_FRAMES = 32, 40


def jpeg(bgr: np.ndarray) -> bytes:
    ok, data = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, 90])
    if not ok:
        raise SystemExit("error: cannot encode a JPEG")
    return bytes(data.tobytes())


def object_photo(obj: str, seed: int = 5) -> tuple[bytes, KnownFocal]:
    """A 1280x720 JPEG of the object, near and oblique, without lens distortion, and its
    camera (the renderer's pinhole)."""
    profile = load_profile(obj)
    plan = plan_dataset(DatasetSpec("free", 2, 0, 9, seed, profile))
    view = next(v for v, k in zip(plan.views, plan.classes, strict=True) if k == 1)
    view = type(view)(**{**view.__dict__, "k1": 0.0})
    pool = BackgroundPool(SIZE, shipped_backgrounds())  # the default pool: GBs at 1280x720
    renderer = Renderer(profile, SIZE, jitter=False, backgrounds=pool, seed=seed)
    rgb = renderer.render(view, 0, np.random.default_rng(0))
    K = intrinsics(SIZE, view.focal_scale)
    camera = KnownFocal(K[0, 0], "camera", SIZE, K[1, 1], K[0, 2], K[1, 2], (0.0,) * 5)
    return jpeg(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)), camera


def empty_photo() -> bytes:
    bgr = cv2.imread(str(NO_OBJECT), cv2.IMREAD_COLOR)
    if bgr is None:
        raise SystemExit(f"error: cannot read {NO_OBJECT}")
    return jpeg(cv2.resize(bgr, SIZE, interpolation=cv2.INTER_LINEAR))


def background_photos() -> list[bytes]:
    """The shipped background photos of 320 px or more, as 1280x720 JPEGs."""
    return [
        jpeg(cv2.resize(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), SIZE, interpolation=cv2.INTER_AREA))
        for rgb in shipped_backgrounds()
        if max(rgb.shape[:2]) >= 320
    ]


def paired_ms(works: list[Callable[[], object]], seconds: float, repeat: int) -> list[float]:
    """Each of `works`' best over `repeat` rounds of its mean ms per call, the works called in
    turn within each round (one of each, again, for at least `seconds`): both sides of a
    ratio timed under the same load and clock."""
    for work in works:
        work()  # warm-up
    best = [math.inf] * len(works)
    for _ in range(repeat):
        spent, calls, start = [0.0] * len(works), 0, time.perf_counter()
        while time.perf_counter() - start < seconds or calls == 0:
            for i, work in enumerate(works):
                t0 = time.perf_counter()
                work()
                spent[i] += time.perf_counter() - t0
            calls += 1
        best = [min(b, 1000 * t / calls) for b, t in zip(best, spent, strict=True)]
    return best


def measure(obj: str, seconds: float, repeat: int) -> list[list[str]]:
    """The rows of one model: each photo, ms off and on, the ratio, within the budget."""
    model = PoseModel.load(ROOT / "models" / f"{MODELS[obj]}.onnx", intra_op_threads=1)
    off, on = (Predictor(model, Settings(refine=r)) for r in (False, True))
    board, camera = object_photo(obj)
    backgrounds = background_photos()
    cases = [("object, nothing known", [board], None, BUDGET_OBJECT),
             ("object, camera registered", [board], camera, BUDGET_OBJECT),
             ("no object", [empty_photo()], None, BUDGET_EMPTY),
             (f"no object, {len(backgrounds)} backgrounds (all)", backgrounds, None,
              BUDGET_EMPTY)]  # fmt: skip
    rows = []
    for what, photos, known, budget in cases:
        answers = [on.predict([(None, d)], "whole", known).results[0] for d in photos]
        source = ", ".join(sorted({r.corners_source or "-" for r in answers}))

        def calls(p: Predictor, photos: list[bytes] = photos, k: KnownFocal | None = known) -> None:
            for data in photos:
                p.predict([(None, data)], "whole", k)

        total = paired_ms([lambda p=p: calls(p) for p in (off, on)], seconds, repeat)
        ms = [t / len(photos) for t in total]  # per photo
        ratio = ms[1] / ms[0]
        # a ratio within the timer's noise of the budget counts as within it
        ok = "yes" if ratio <= budget * 1.05 else "no"
        rows.append([f"`{model.name}`", what, source, f"{ms[0]:.1f}", f"{ms[1]:.1f}",
                     f"{ratio:.2f}x", f"{budget:g}x", ok])  # fmt: skip
        print(" | ".join(rows[-1]), flush=True)
    return rows


def stream(
    predictor: Predictor, frames: list[bytes], known: KnownFocal | None
) -> tuple[list[ImageResult], float]:
    """Each frame's answer as a stream gives it (`Predictor.stream_frame`, the network every
    `stream_track_every` frames of the predictor's settings) and the mean ms per frame."""
    results, track, since = [], None, 0
    start = time.perf_counter()
    for data in frames:
        job = predictor.admit([(None, data)], predictor.options("whole", known))
        prediction, since = predictor.stream_frame(job, track, since)
        result = prediction.results[0]
        track = None
        if result.corners is not None and result.class_id:
            present = 1.0 - result.probabilities[0]
            track = Track(np.array(result.corners), prediction.kappas[0], present)
        results.append(result)
    return results, 1000 * (time.perf_counter() - start) / len(frames)


def spread_cm(sequences: list[list[ImageResult]]) -> float:
    """RMS distance (cm) of the answers' camera centres from their sequence's mean, pooled
    over the sequences."""
    offsets = []
    for results in sequences:
        centres = np.array([r.pose.camera_cm for r in results if r.pose is not None])
        if len(centres):
            offsets.append(centres - centres.mean(0))
    if not offsets:
        return float("nan")
    return float(np.sqrt((np.concatenate(offsets) ** 2).sum(1).mean()))


def stream_rows() -> list[list[str]]:
    """The streams' rows: still sequence (ms, frames/s, spread) and video-like (class)."""
    model = PoseModel.load(ROOT / "models" / f"{MODELS['charuco']}.onnx", intra_op_threads=1)
    board, _ = object_photo("charuco")
    bgr = cv2.imdecode(np.frombuffer(board, np.uint8), cv2.IMREAD_COLOR).astype(np.float64)
    rng = np.random.default_rng(0)
    stills = [[jpeg(np.clip(bgr + rng.normal(0, 2, bgr.shape), 0, 255).astype(np.uint8))
               for _ in range(STILL_FRAMES)] for _ in range(STILL_SEQUENCES)]  # fmt: skip
    with (VIDEO / "labels.csv").open(newline="", encoding="utf-8") as f:
        labels = sorted(csv.DictReader(f), key=lambda row: row["file"])
    frames = [(VIDEO / row["file"]).read_bytes() for row in labels]
    calibration = camera_of_row(labels[0])
    camera = None if calibration is None else KnownFocal.of_camera(calibration)
    rows = []
    for what, every in (("network every frame", 1), ("tracked, network every 10th", 10)):
        predictor = Predictor(model, Settings(stream_track_every=every))
        runs = [stream(predictor, still, None) for still in stills]
        answers = [answer for run in runs for answer in run[0]]
        ms = float(np.mean([run[1] for run in runs]))
        seen, _ = stream(predictor, frames, camera)
        truth = [int(row["class"]) for row in labels]
        right = np.mean([r.class_id == k for r, k in zip(seen, truth, strict=True)])
        tracked = np.mean([bool(r.tracked) for r in answers])
        spread = spread_cm([run[0] for run in runs])
        rows.append([what, f"{100 * tracked:.0f}", f"{ms:.1f}", f"{1000 / ms:.1f}",
                     f"{spread:.4f}", f"{100 * right:.1f}"])  # fmt: skip
        print(" | ".join(rows[-1]), flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=2.0, help="length of one round")
    parser.add_argument("--repeat", type=int, default=3, help="rounds; the best counts")
    parser.add_argument("--write-docs", action="store_true", help="update docs/benchmarks.md")
    args = parser.parse_args()
    when = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    header = (
        f"`.venv/bin/python benchmarks/bench_refine.py --seconds {args.seconds:g} --repeat "
        f"{args.repeat}`, {when}, {platform.machine()}, {os.cpu_count()} CPUs, load average "
        f"{os.getloadavg()[0]:.2f} at start. ms per 1280x720 JPEG through whole mode, best of "
        "the rounds."
    )
    print(header)
    rows = [row for obj in MODELS for row in measure(obj, args.seconds, args.repeat)]
    head = ["model", "photo", "corners", "refine off ms", "refine on ms", "on / off", "budget",
            "within"]  # fmt: skip
    streams = stream_rows()
    stream_head = ["stream", "tracked %", "ms per frame", "frames/s per core",
                   "camera_cm spread (still), cm", "class right (video-like) %"]  # fmt: skip
    body = [header, "", *table(head, rows), "",
            f"Streams, `{MODELS['charuco']}` on one thread: {STILL_SEQUENCES} still 1280x720 "
            f"sequences of {STILL_FRAMES} frames; the ChArUco val source's frames in order "
            "(640x360, its camera registered).", "", *table(stream_head, streams), "",
            f"* load average {os.getloadavg()[0]:.2f} at end"]  # fmt: skip
    print("\n".join(body))
    if args.write_docs:
        write_section(DOCS, "bench_refine", "Refinement at the photo's resolution", body)


if __name__ == "__main__":
    main()
