"""CPU inference cost of the shipped models against the SPEC network of the same input size,
measured in one run: the model issue's budget is an ONNX file under 10 MB and inference per
image within 2x of the SPEC network at the same input size.

For every models/*.onnx, with onnxruntime on one thread (`service.pipeline.model.PoseModel`, as one
service worker runs it): the file's size; ms per image of the graph alone (`PoseModel.run`)
at batch 1 and batch 64, on a board photo (train/assets/real/chessboard-stereo/left01.jpg)
brought to the network's input as the service does; and ms per image of the service's whole
mode (preprocessing + graph + the zoom pass where the graph serves it, `service.pipeline.zoom`) on
that photo and on a photo without the board (train/assets/backgrounds/photos/camera.jpg),
where the zoom pass searches its tiles. Each time is the best of `--repeat` rounds of
`--seconds` each. The ratios are to the SPEC network (the models whose card names no
architecture: chessboard-noC-*) of the same input size, graph to graph at batch 1.

    .venv/bin/python benchmarks/bench_inference.py [--seconds 1] [--repeat 3] [--write-docs]
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import onnxruntime
from docs_section import write_section  # benchmarks/, the script's own folder

from service.core.paths import DEFAULT_MODEL_NAME
from service.core.preprocess import to_network_input
from service.pipeline.model import PoseModel
from service.pipeline.zoom import detail_of, zoomed
from train.markdown import table

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs" / "benchmarks.md"
BOARD = ROOT / "train/assets/real/chessboard-stereo/left01.jpg"
NO_BOARD = ROOT / "train/assets/backgrounds/photos/camera.jpg"
SIZE_LIMIT_MB, TIME_LIMIT = 10.0, 2.0  # the model issue's budget


def best_ms(work: Callable[[], object], images: int, seconds: float, repeat: int) -> float:
    """Best over `repeat` rounds of the mean ms per image of `work` (one call = `images`
    images), each round calling it for at least `seconds`."""
    work()  # warm-up
    rounds = []
    for _ in range(repeat):
        calls, start = 0, time.perf_counter()
        while (elapsed := time.perf_counter() - start) < seconds or calls == 0:
            work()
            calls += 1
        rounds.append(1000 * elapsed / (calls * images))
    return min(rounds)


def rgb(path: Path) -> np.ndarray:
    """A photo as RGB uint8 [H, W, 3]."""
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise SystemExit(f"error: cannot read {path}")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def measure(path: Path, photos: dict[str, np.ndarray], seconds: float, repeat: int) -> dict:
    """Size and times of one model (module doc)."""
    model = PoseModel.load(path, intra_op_threads=1)
    size = model.input_size
    x = to_network_input(photos["board"], size)[None]
    batch = np.repeat(x, 64, axis=0)
    row = {
        "name": path.stem,
        "spec": "architecture" not in model.card,
        "size": size,
        "mb": path.stat().st_size / 1e6,
        "graph 1": best_ms(lambda: model.run(x), 1, seconds, repeat),
        "graph 64": best_ms(lambda: model.run(batch), 64, seconds, repeat),
    }
    for kind, photo in photos.items():

        def whole(photo: np.ndarray = photo) -> object:
            detail = [detail_of(photo, size)] if model.zooms else None
            return zoomed(model, to_network_input(photo, size)[None], None, detail=detail)

        row[f"service {kind}"] = best_ms(whole, 1, seconds, repeat)
    return row


def budget(row: dict, ratio: float | None) -> str:
    """Whether a model keeps the issue's budget: "-" for the SPEC networks (the reference)."""
    if row["spec"]:
        return "-"
    return (
        "yes" if row["mb"] < SIZE_LIMIT_MB and ratio is not None and ratio <= TIME_LIMIT else "no"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", type=Path, default=ROOT / "models", help="folder of .onnx")
    parser.add_argument("--seconds", type=float, default=1.0, help="length of one round")
    parser.add_argument("--repeat", type=int, default=3, help="rounds; the best counts")
    parser.add_argument("--write-docs", action="store_true", help="update docs/benchmarks.md")
    args = parser.parse_args()
    paths = sorted(args.models.glob("*.onnx"))
    if not paths:
        raise SystemExit(f"error: no .onnx model in {args.models}")
    photos = {"board": rgb(BOARD), "no board": rgb(NO_BOARD)}
    when = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    header = (
        f"`.venv/bin/python benchmarks/bench_inference.py --seconds {args.seconds:g} --repeat "
        f"{args.repeat}`, {when}, {platform.machine()}, {os.cpu_count()} CPUs, onnxruntime "
        f"{onnxruntime.__version__} on 1 thread, load average {os.getloadavg()[0]:.2f} at start. "
        "ms per image, best of the rounds."
    )
    print(header)
    rows = []
    for path in paths:
        rows.append(measure(path, photos, args.seconds, args.repeat))
        print(f"{path.stem}: graph {rows[-1]['graph 1']:.2f} ms per image at batch 1")
    spec = {r["size"]: r["graph 1"] for r in rows if r["spec"]}
    columns = ["graph 1", "graph 64", "service board", "service no board"]
    body = []
    for r in rows:
        ratio = r["graph 1"] / spec[r["size"]] if r["size"] in spec else None
        body.append(
            [f"`{r['name']}`", f"{r['size'][0]}x{r['size'][1]}", f"{r['mb']:.2f}"]
            + [f"{r[c]:.2f}" for c in columns]
            + ["-" if ratio is None else f"{ratio:.2f}x"]
            + [budget(r, ratio)]
        )
    lines = [
        header,
        "",
        *table(
            [
                "model",
                "input",
                "ONNX MB",
                "graph, batch 1",
                "graph, batch 64",
                "service, board photo",
                "service, no board",
                "graph / SPEC network",
                f"< {SIZE_LIMIT_MB:g} MB and <= {TIME_LIMIT:g}x",
            ],  # fmt: skip
            body,
        ),
        "",
        "graph: `PoseModel.run` on the network input; service: preprocessing of the photo, the "
        "graph and the zoom pass (models with its inputs: a second look at a small board, and "
        "where no board was found the tile nearest the frame's corner guess, "
        "POSE_ZOOM_SEARCH_TILES). The SPEC network of each input size is the reference of the "
        "ratio (graph, batch 1).",
    ]
    default = next((r for r in rows if r["name"] == DEFAULT_MODEL_NAME), None)
    if default is not None and default["size"] in spec:
        lines += [
            "",
            f"- the default ({DEFAULT_MODEL_NAME}): {default['mb']:.2f} MB, its graph "
            f"{default['graph 1'] / spec[default['size']]:.2f}x the SPEC network's at "
            f"{default['size'][0]}x{default['size'][1]}; the service's answer on a photo "
            f"without the board costs {default['service no board'] / default['graph 1']:.1f}x "
            "its graph (the zoom pass's search).",
        ]
    print("\n".join(lines))
    if args.write_docs:
        write_section(DOCS, "bench_inference", "Inference", lines)
        print(f"wrote {DOCS}")


if __name__ == "__main__":
    main()
