"""The pose and the learned camera on real photos: class accuracy and camera-centre error.

Every board photo of the corpus's val and test sources (one source = one camera) goes through
the service's HTTP app in-process (`/v1/predict`, whole mode, default settings) three ways:

    estimated   no focal length (the view's estimate, `fx_source: "estimated"`)
    true fx     the photo's calibrated fx (`?fx=`, the labels' camera matrix)
    learned     a camera learned by `POST /v1/cameras` from up to 10 OTHER photos of the same
                source (never the photo answered), then `?camera=ID`; where no camera can be
                learned (422), the photo is answered as `estimated` and counted

For each: the class accuracy, near/far right, and the camera centre's error as a fraction of
the true distance (median); for `learned` also the learned fx's error (median) and how many
photos got a camera. Then each source's photos are sent one by one, in order, on one
`WS /v1/stream` without fx (at most 30): the first frame answered with `fx_source: "stream"`
and the error of the stream's fx on its last frame. The test sources are reported, never
used to choose anything. Writes a markdown page (default docs/pose_accuracy.md) with the
date and the machine. `--width W` sends every photo reduced to W px wide (OpenCV's area
resampling, JPEG quality 95; the true fx scaled alike): issue 49's "160 px not lower than
today" is `--width 160`.

    python scripts/pose_accuracy.py [--width 160 --out docs/pose_accuracy_160.md]
"""

from __future__ import annotations

import argparse
import csv
import sys
import tempfile
import time
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

import cv2
import numpy as np
from fastapi.testclient import TestClient

from service.app import create_app
from service.core.dataset import corpus_sources, read_splits
from service.core.paths import ASSETS_DIR, REPO_ROOT
from service.core.regions import is_far
from service.settings import Settings
from train.markdown import table, written_by

CORPUS = ASSETS_DIR / "real" / "corpus"
#: Photos a camera is learned from, at most.
LEARN_FROM = 10
WAYS = ("estimated", "true fx", "learned")


@dataclass
class Tally:
    """The answers of one way on one source."""

    right: list[bool] = field(default_factory=list)
    depth_right: list[bool] = field(default_factory=list)
    centre_error: list[float] = field(default_factory=list)  # |c - c_true| / |c_true|
    fx_error: list[float] = field(default_factory=list)  # learned: |fx - fx_true| / fx_true
    learned: int = 0

    def add(self, result: dict, label: int, centre: np.ndarray) -> None:
        self.right.append(result["class_id"] == label)
        found = result["class_id"] != 0
        self.depth_right.append(found and is_far(result["class_id"]) == is_far(label))
        pose = result.get("pose")
        error = np.inf if pose is None else np.linalg.norm(np.array(pose["camera_cm"]) - centre)
        self.centre_error.append(float(error / np.linalg.norm(centre)))

    def row(self) -> list[str]:
        n = len(self.right)
        return [
            f"{100 * np.mean(self.right):.1f}",
            f"{100 * np.mean(self.depth_right):.1f}",
            f"{100 * np.median(self.centre_error):.1f}",
            f"{self.learned}/{n}" if self.fx_error else "",
            f"{100 * np.median(self.fx_error):.1f}" if self.fx_error else "",
        ]


def _scale(row: dict[str, str], width: int | None) -> float:
    """The factor from the labels' px to the px of the photo sent `width` px wide (None: as
    stored)."""
    return 1.0 if width is None else width / int(row["width"])


@cache  # a photo is sent again with each camera learned from it
def _bytes(path: Path, width: int | None) -> bytes:
    """The photo's file as sent: as stored (`width` None), or reduced to `width` px wide."""
    data = path.read_bytes()
    if width is None:
        return data
    bgr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if bgr is None:
        sys.exit(f"error: cannot decode {path}")
    height = max(1, round(bgr.shape[0] * width / bgr.shape[1]))
    small = cv2.resize(bgr, (width, height), interpolation=cv2.INTER_AREA)
    return cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()


def _photo(
    folder: Path, row: dict[str, str], width: int | None
) -> tuple[str, tuple[str, bytes, str]]:
    return ("image", (row["file"], _bytes(folder / row["file"], width), "image/jpeg"))


def measure(client: TestClient, folder: Path, width: int | None) -> dict[str, Tally]:
    """The three ways on every photo of one source (one camera), sent `width` px wide."""
    with (folder / "labels.csv").open(newline="", encoding="utf-8") as handle:
        rows = [r for r in csv.DictReader(handle) if int(r["class"]) != 0 and r.get("fx")]
    tallies = {way: Tally() for way in WAYS}
    for i, row in enumerate(rows):
        label, centre = int(row["class"]), np.array([float(row[f"cam_{a}"]) for a in "xyz"])
        photo = [_photo(folder, row, width)]
        fx = float(row["fx"]) * _scale(row, width)  # px of the photo as sent
        answers = {
            "estimated": client.post("/v1/predict", files=photo).json(),
            "true fx": client.post(f"/v1/predict?fx={fx}", files=photo).json(),
        }
        others = [rows[(i + k) % len(rows)] for k in range(1, min(LEARN_FROM, len(rows) - 1) + 1)]
        learned = client.post("/v1/cameras", files=[_photo(folder, r, width) for r in others])
        if learned.status_code == 201:
            camera = learned.json()
            query = f"/v1/predict?camera={camera['id']}"
            answers["learned"] = client.post(query, files=photo).json()
            client.delete(f"/v1/cameras/{camera['id']}")
            tallies["learned"].learned += 1
            # px of the photo as sent, the size the camera was learned at
            tallies["learned"].fx_error.append(abs(camera["fx"] - fx) / fx)
        else:
            answers["learned"] = answers["estimated"]
        for way, answer in answers.items():
            if "results" not in answer:
                sys.exit(f"error: {folder.name}/{row['file']} ({way}): {answer}")
            tallies[way].add(answer["results"][0], label, centre)
    return tallies


def stream(client: TestClient, folder: Path, width: int | None, frames: int = 30) -> list[str]:
    """One source's photos (sent `width` px wide) on one stream without fx -> the row:
    photos sent, the first frame (1-based) answered with the stream's camera, its fx error %
    on the last frame."""
    with (folder / "labels.csv").open(newline="", encoding="utf-8") as handle:
        rows = [r for r in csv.DictReader(handle) if int(r["class"]) != 0 and r.get("fx")]
    rows = rows[:frames]
    first, fx = None, None
    with client.websocket_connect("/v1/stream") as ws:
        ws.receive_json()
        for i, row in enumerate(rows):
            ws.send_bytes(_bytes(folder / row["file"], width))
            answer = ws.receive_json()
            if answer.get("fx_source") == "stream":
                first = first or i + 1
                sent = _scale(row, width) * max(int(row["width"]), int(row["height"]))
                fx = answer["fx"] * sent / max(answer["image_size"])
    fx_true = float(rows[-1]["fx"]) * _scale(rows[-1], width)
    error = "" if fx is None else f"{100 * abs(fx - fx_true) / fx_true:.1f}"
    return [str(len(rows)), "never" if first is None else str(first), error]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=REPO_ROOT / "docs/pose_accuracy.md")
    parser.add_argument("--width", type=int, help="send the photos reduced to this width, px")
    args = parser.parse_args()
    if args.width is not None and args.width < 16:
        parser.error(f"--width {args.width}: 16 px or more")
    splits = read_splits(CORPUS / "splits.toml")
    sources = [p for p in corpus_sources(CORPUS) if p.parent.name == "boards"]
    db = Path(tempfile.mkdtemp(prefix="pose-accuracy-")) / "cameras.db"
    rows, totals = [], {(s, w): Tally() for s in ("val", "test") for w in WAYS}
    streams = []
    start = time.perf_counter()
    with TestClient(create_app(Settings(camera_db=db))) as client:
        while client.get("/readyz").status_code != 200:
            time.sleep(0.1)
        for folder in sources:
            split = splits.get(folder.name)
            if split not in ("val", "test"):
                continue
            tallies = measure(client, folder, args.width)
            streams.append([split, folder.name, *stream(client, folder, args.width)])
            for way, tally in tallies.items():
                rows.append([split, folder.name, way, len(tally.right), *tally.row()])
                total = totals[split, way]
                for name in ("right", "depth_right", "centre_error", "fx_error"):
                    getattr(total, name).extend(getattr(tally, name))
                total.learned += tally.learned
            print(f"{folder.name}: done ({time.perf_counter() - start:.0f} s)", flush=True)
    summary = [[s, w, len(totals[s, w].right), *totals[s, w].row()] for s, w in totals]
    header = ["class %", "near/far %", "centre error % (median)", "learned", "fx error %"]
    lines = [
        "# The pose and the learned camera on real photos",
        "",
        written_by(" ".join(["python scripts/pose_accuracy.py", *sys.argv[1:]]))
        + " Board photos of the corpus's val and test sources (one source = one camera) "
        f"{'as stored' if args.width is None else f'reduced to {args.width} px wide'} "
        "through the service's HTTP app, whole mode, default settings and model; `learned`: "
        f"a camera learned from up to {LEARN_FROM} other photos of the source "
        "(`POST /v1/cameras`), the photo answered never among them. Centre error: |c - "
        "c_true| / |c_true| (an answer without a pose counts as infinite).",
        "",
        "## Per split",
        "",
        *table(["split", "focal length", "photos", *header], summary),
        "",
        "## Per source",
        "",
        *table(["split", "source", "focal length", "photos", *header], rows),
        "",
        "## The stream learns its camera",
        "",
        *table(["split", "source", "frames sent", "first stream fx", "fx error % (last)"], streams),
        "",
    ]
    args.out.write_text("\n".join(lines), encoding="utf-8")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
