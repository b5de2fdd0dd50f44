"""What the refinement at the photo's resolution adds: per object, set and what is known of the
camera, through the service's own path (`service.predictor.Predictor`, the code behind
`/v1/predict`), with the refinement off (the network's corners) and on.

Sets:
* real: the val and test sources of the ChArUco frames (train/assets/real/charuco, 640x360)
  and of the chessboard corpus (train/assets/real/corpus, 640 px wide); `--extra NAME=DIR`
  adds a folder of photos with a labels.csv of the same columns (e.g. the ChArUco frames at
  their own 1280x720, extracted from the source videos);
* renders: independent draws of each object's profile (seeds no training run uses), at
  160x120 and 640x480, SPEC blur 0-3 (at 640x480 the 160x120 kernel scaled 4x), half of
  them class 0.

What is known of the camera: nothing; `registered` (each photo's calibration from its
labels: fx, fy, principal point and OpenCV's 5 coefficients, as `POST /v1/cameras` JSON with
`dist`); `learned` (a camera learned by `POST /v1/cameras` multipart from 10 frames of the
source spread over it, answered on the others). Columns: class right; the corners' median
error px of the set's images against the labels; near/far and x/y side right among the
photos whose object was found; found; refined (`corners_source`); the median ms per image
(the refinement's time budget at its largest, 10 s, so that the answers do not depend on
the machine's load; the times do: `benchmarks/bench_refine.py` measures them).

    python scripts/refine_accuracy.py [--count 100] [--extra charuco:cam2-1280=/tmp/full/cam2] \
        [--model charuco=ZERO_SHOT.onnx] [--out docs/refinement.md]
"""

from __future__ import annotations

import argparse
import csv
import sys
import tomllib
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from service.cameras.learning import learn_camera
from service.cameras.schema import CameraOut
from service.cameras.store import known_focal
from service.core.dataset import camera_of_row, corners_of_row
from service.core.paths import REPO_ROOT
from service.core.profile import load_profile
from service.pipeline.focal import KnownFocal
from service.pipeline.model import PoseModel
from service.pipeline.predictor import Predictor
from service.settings import Settings
from train.compare.answers import Photo, answer_all
from train.markdown import pct_cell, table, written_by
from train.network.export import repo_path
from train.synth.background import BackgroundPool, procedural_backgrounds, shipped_backgrounds

MODELS = {
    "chessboard": "chessboard-corners-160x120",
    "charuco": "charuco-corners-160x120",
    "book": "book-corners-160x120",
}
REAL = {
    "charuco": REPO_ROOT / "train/assets/real/charuco",
    "chessboard": REPO_ROOT / "train/assets/real/corpus",
}
LEARN_FROM = 10  # frames a learned camera is learned from
RENDER_SEED = 970_000  # far from every recipe's seeds (recipes/*.toml)
RENDER_SIZES = ((160, 120), (640, 480))


def folder_photos(folder: Path) -> list[Photo]:
    """The photos of a labelled folder (labels.csv beside images/)."""
    with (folder / "labels.csv").open(newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    photos = []
    for r in rows:
        camera = camera_of_row(r)
        known = None if camera is None else KnownFocal.of_camera(camera)
        photos.append(
            Photo((folder / r["file"]).read_bytes(), int(r["class"]), corners_of_row(r), known)
        )
    return photos


def real_sources(obj: str) -> Iterator[tuple[str, str, Path]]:
    """(split, source name, folder) of an object's val and test sources with labels."""
    root = REAL[obj]
    splits = tomllib.loads((root / "splits.toml").read_text())["splits"]
    for name, split in sorted(splits.items(), key=lambda kv: (kv[1], kv[0])):
        folder = root / "boards" / name
        if split in ("val", "test") and (folder / "labels.csv").is_file():
            yield split, name, folder


def _blurred(rgb: np.ndarray, level: int, size: tuple[int, int]) -> np.ndarray:
    """SPEC blur `level` of a render of `size`: the 160x120 kernel scaled with the width."""
    from service.core.blur import KERNELS, gaussian_taps

    if level == 0:
        return rgb
    k, sigma = KERNELS[2][level]
    f = size[0] / 160
    taps = gaussian_taps(max(1, round(k * f)), sigma * f)
    return cv2.sepFilter2D(rgb, -1, taps, taps, borderType=cv2.BORDER_REPLICATE)


def backgrounds(size: tuple[int, int]) -> BackgroundPool:
    """The shipped background photos and procedural textures at `size` (the renderer's
    default pool adds the corpus's photos: GBs of memory at 640x480)."""
    w, h = size
    return BackgroundPool(size, shipped_backgrounds() + procedural_backgrounds(8, (2 * w, 2 * h)))


def renders(obj: str, size: tuple[int, int], blur: int, count: int, seed: int) -> list[Photo]:
    """`count` renders of the object's profile at `size` and `blur` (variant free)."""
    from train.synth.generate import DatasetSpec, plan_dataset
    from train.synth.render import Renderer

    profile = load_profile(obj)
    plan = plan_dataset(DatasetSpec("free", 2, 0, count, seed, profile))
    renderer = Renderer(profile, size, jitter=True, backgrounds=backgrounds(size), seed=seed)
    rng = np.random.default_rng(seed)
    photos = []
    for label, view in zip(plan.classes, plan.views, strict=True):
        rgb = _blurred(renderer.render(view, 0, rng), blur, size)
        ok, png = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        corners = None if view is None else view.object_corners(profile, size)
        photos.append(Photo(png.tobytes(), int(label), corners, None))
    return photos


def score(predictor: Predictor, photos: list[Photo], known: list[KnownFocal | None]) -> list[str]:
    """The table cells of one set under one condition (the module doc's columns)."""
    a = answer_all(predictor, photos, known).as_dict()
    px = a["corner_px"]
    return [
        pct_cell(a["accuracy"]),
        "-" if px is None else f"{px:.2f}",
        pct_cell(a["near_far"]),
        pct_cell(a["side"]),
        pct_cell(a["found"]),
        pct_cell(a["refined"]),
        f"{a['ms']:.0f}",
    ]


def learned(predictor: Predictor, photos: list[Photo]) -> tuple[KnownFocal | None, list[int]]:
    """A camera learned from `LEARN_FROM` of the photos spread over the source and the
    indices of the others; None (all indices) where it cannot be learned."""
    step = max(1, len(photos) // LEARN_FROM)
    chosen = list(range(0, len(photos), step))[:LEARN_FROM]
    rest = [i for i in range(len(photos)) if i not in chosen]
    try:
        fields = learn_camera(predictor, [(None, photos[i].data) for i in chosen])
    except ValueError:
        return None, list(range(len(photos)))
    stored = CameraOut(**fields, id="learned", created="now")  # as the store answers it
    return known_focal(stored), rest


CONDITIONS = ("network", "refined")  # the refinement off, on
HEADER = ["set", "camera", "corners", "class %", "corner px", "near/far %", "x/y side %",
          "found %", "refined %", "ms"]  # fmt: skip


def set_rows(
    predictors: dict[str, Predictor], name: str, photos: list[Photo], real: bool
) -> list[list[str]]:
    """The table rows of one set: each condition with nothing known, and for real photos
    with the registered and the learned camera."""
    rows = []
    for condition, predictor in predictors.items():
        rows.append([name, "none", condition, *score(predictor, photos, [None] * len(photos))])
        if real:
            cameras = [p.camera for p in photos]
            rows.append([name, "registered", condition, *score(predictor, photos, cameras)])
            camera, rest = learned(predictor, photos)
            others = [photos[i] for i in rest]
            cells = score(predictor, others, [camera] * len(others))
            rows.append([name, "learned" if camera else "not learned", condition, *cells])
        print("\n".join(" | ".join(r) for r in rows[-3 if real else -1 :]), flush=True)
    return rows


def object_rows(obj: str, count: int, extra: list[tuple[str, Path]], path: Path) -> list[list[str]]:
    """Every set of one object answered by the model file `path`: its real sources (and
    `extra` folders), then its renders."""
    model = PoseModel.load(path)
    # the budget at its largest: the answers do not depend on the machine's load
    settings = {c: Settings(refine=c == "refined", refine_budget_ms=10_000) for c in CONDITIONS}
    predictors = {c: Predictor(model, settings[c]) for c in CONDITIONS}
    rows = []
    sources = list(real_sources(obj)) if obj in REAL else []
    for split, name, folder in sources:
        rows += set_rows(predictors, f"{split} {name}", folder_photos(folder), real=True)
    for name, folder in extra:
        rows += set_rows(predictors, name, folder_photos(folder), real=True)
    for size in RENDER_SIZES:
        for blur in range(4):
            photos = renders(obj, size, blur, count, RENDER_SEED + 10 * blur + size[0])
            rows += set_rows(predictors, f"renders {size[0]}x{size[1]} blur {blur}", photos, False)
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--objects", nargs="+", default=list(MODELS), choices=list(MODELS))
    parser.add_argument("--count", type=int, default=100, help="renders per set (>= 9)")
    parser.add_argument(
        "--extra", action="append", default=[], metavar="OBJECT:NAME=DIR",
        help="a labelled folder of real photos of OBJECT, e.g. charuco:cam2-1280=/tmp/cam2",
    )  # fmt: skip
    parser.add_argument(
        "--model", action="append", default=[], metavar="OBJECT=MODEL.onnx",
        help="answer OBJECT with this model file instead of its shipped one (e.g. zero-shot)",
    )  # fmt: skip
    parser.add_argument("--out", type=Path, default=REPO_ROOT / "docs/refinement.md")
    args = parser.parse_args(argv)
    extra: dict[str, list[tuple[str, Path]]] = {}
    for item in args.extra:
        head, _, folder = item.partition("=")
        obj, _, name = head.partition(":")
        if obj not in MODELS or not name or not (Path(folder) / "labels.csv").is_file():
            parser.error(f"--extra {item!r}: OBJECT:NAME=DIR with DIR/labels.csv")
        extra.setdefault(obj, []).append((name, Path(folder)))
    models: dict[str, Path] = {}
    for item in args.model:
        obj, _, path = item.partition("=")
        if obj not in MODELS or not Path(path).is_file():
            parser.error(f"--model {item!r}: OBJECT=MODEL.onnx with an existing file")
        models[obj] = Path(path)
    command = "python scripts/refine_accuracy.py " + " ".join(argv or sys.argv[1:])
    lines = ["# What the refinement at the photo's resolution adds", "", written_by(command), ""]
    lines += [line for line in (__doc__ or "").split("\n\n")[0:2]] + [""]
    for obj in args.objects:
        path = models.get(obj, REPO_ROOT / "models" / f"{MODELS[obj]}.onnx")
        rows = object_rows(obj, args.count, extra.get(obj, []), path)
        lines += [f"## {obj} (`{repo_path(path)}`)", "", *table(HEADER, rows), ""]
    args.out.write_text("\n".join(lines) + "\n", encoding="utf-8")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
