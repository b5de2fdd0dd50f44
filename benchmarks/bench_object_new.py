"""From a new picture to a served model (issue 51's first bar), timed end to end on this machine:
a running service (`bench_models.serve`, one worker, on a model folder holding the default
model), then, timed, `planar-pose object new NAME --texture PICTURE` writing the profile, its
sample sheet and the zero-shot model into that folder (a fresh process: imports included),
`POST /v1/models/reload`, and the first `POST /v1/predict?model=NAME-corners-160x120` of a
render of the object (one of the renders `object new` measured the model on).

Pictures: the held-back test textures that are photographs (`train.synth.textures
.HELD_OUT_PHOTOS`: no network trained on them) unless `--pictures` names others.

    .venv/bin/python benchmarks/bench_object_new.py [--pictures A.jpg ...] [--write-docs]
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

import cv2
import httpx
from bench_models import serve  # benchmarks/, the script's own folder
from docs_section import write_section

from service.core.paths import DEFAULT_MODEL
from train.markdown import table
from train.synth.textures import HELD_OUT_PHOTOS

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs" / "benchmarks.md"
BACKGROUNDS = ROOT / "train" / "assets" / "backgrounds"
TARGET_S = 120.0
WIDTH_CM = 30.0  # the object's width; its height from the picture's aspect


def one_picture(picture: Path, models: Path, work: Path, base: str) -> list[str]:
    """Time `object new`, the reload and the first answer for `picture` -> a table row."""
    name = "bench-" + "".join(c if c.isalnum() else "-" for c in picture.stem.lower())
    run = work / "runs" / name
    image = cv2.imread(str(picture), cv2.IMREAD_COLOR)
    if image is None:
        raise SystemExit(f"error: not a readable image: {picture}")
    size = (f"{WIDTH_CM:g}", f"{WIDTH_CM * image.shape[0] / image.shape[1]:.3f}")  # its aspect
    command = [sys.executable, "-m", "train.cli", "object", "new", name, "--texture",
               str(picture), "--size", *size, "--profiles", str(work / "profiles"),
               "--models", str(models), "--run", str(run)]  # fmt: skip
    start = time.perf_counter()
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True)
    made = time.perf_counter()
    if done.returncode != 0:
        raise SystemExit(f"error: object new failed:\n{done.stdout}\n{done.stderr}")
    reload = httpx.post(base + "/v1/models/reload", timeout=60)
    reloaded = time.perf_counter()
    photo = sorted((run / "data" / "zero-shot-b0" / "images").glob("*.png"))[0].read_bytes()
    model = f"{name}-corners-160x120"
    answer = httpx.post(f"{base}/v1/predict?model={model}", files={"image": photo}, timeout=60)
    answered = time.perf_counter()
    if reload.status_code != 200 or answer.status_code != 200:
        raise SystemExit(f"error: reload {reload.status_code}, predict {answer.text[:300]}")
    total = answered - start
    row = [picture.name, f"{made - start:.1f}", f"{reloaded - made:.2f}",
           f"{answered - reloaded:.2f}", f"{total:.1f}",
           "yes" if total <= TARGET_S else "no"]  # fmt: skip
    print(" | ".join(row), flush=True)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pictures", nargs="+", type=Path, help="pictures of objects")
    parser.add_argument("--write-docs", action="store_true", help="update docs/benchmarks.md")
    args = parser.parse_args()
    pictures = args.pictures or [BACKGROUNDS / p for p in HELD_OUT_PHOTOS]
    when = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    header = (
        f"`.venv/bin/python benchmarks/bench_object_new.py`, {when}, {platform.machine()}, "
        f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f} at start. Seconds from "
        "the picture to the first answer of its zero-shot model by a running service "
        f"(target <= {TARGET_S:g} s)."
    )
    print(header, flush=True)
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-object-new-") as tmp:
        work, models = Path(tmp), Path(tmp) / "models"
        models.mkdir()
        for suffix in (".onnx", ".json"):
            shutil.copyfile(
                DEFAULT_MODEL.with_suffix(suffix), models / f"{DEFAULT_MODEL.stem}{suffix}"
            )
        with serve(models, None, work / "serve.log", workers=1) as server:
            rows = [one_picture(p, models, work, server.base) for p in pictures]
    head = ["picture", "object new s", "reload s", "first answer s", "total s", "within"]
    body = [header, "", *table(head, rows)]
    print("\n".join(body))
    if args.write_docs:
        write_section(DOCS, "bench_object_new", "From a picture to a served model", body)


if __name__ == "__main__":
    main()
