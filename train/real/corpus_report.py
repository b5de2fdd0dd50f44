"""The corpus's README: sources, photos per region and split, label checks, contact sheets.

Written by `planar-pose corpus report` from the labelled folders (never by hand), so that the
tables always describe the photos that are there.
"""

from __future__ import annotations

import csv
import json
import platform
from collections import Counter
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from service.core.dataset import SPLITS, corpus_sources, read_splits
from service.core.regions import region_of_class
from train.markdown import pct, table
from train.real.corpus import STORE_MAX_SIDE, contact_sheet

SHEET_PER_CLASS = 30

INTRO = """# Real photographs: the corpus

Real photographs of the default object (a printed 9 x 6-inner-corner, 10 x 7-square
chessboard) from public repositories whose licence allows redistribution, and real photos
without it (class 0). One folder per *source* (one camera in one repository), under
`boards/` and `negatives/`, each with the repository's `LICENSE`, `manifest.json` (repository,
commit, folder, licence, camera, calibration) and `labels.csv`. Photos are stored with their
longer side at most 640 px; intrinsics and corners in labels.csv are for the stored size.

How a source is added and labelled: docs/data.md ("Real photographs"). `splits.toml` puts
every source in exactly one split; the **test** sources are fixed, so "real test accuracy"
always means cameras and scenes never used for training or model selection.

This page is written by `planar-pose corpus report`; do not edit it by hand.
"""


def _rows(folder: Path) -> list[dict[str, str]]:
    with (folder / "labels.csv").open(newline="") as fh:
        return list(csv.DictReader(fh))


def _source_line(folder: Path, split: str) -> list[Any]:
    m = json.loads((folder / "manifest.json").read_text())
    src = m["source"]
    cal = m.get("calibration") or []
    rms = ", ".join(f"{c['rms_px']:.2f}" for c in cal) if cal else ""
    sizes = ", ".join(f"{c['size'][0]}x{c['size'][1]}" for c in cal)
    repo = f"[{src['repo']}](https://github.com/{src['repo']})"
    if m.get("kind") == "negative":
        return [f"`{folder.name}`", repo, src["licence"], m["photos"], m["count"], split]
    per_class = " / ".join(str(n) for n in m["class_counts"][1:])
    return [
        f"`{folder.name}`", repo, src["licence"], src.get("camera") or "", sizes, m["photos"],
        m["count"], m["failed"], rms, per_class, split,
    ]  # fmt: skip


def _region_table(counts: dict[str, Counter[int]]) -> list[str]:
    header = ["class", "region", *SPLITS, "all"]
    body = []
    for k in range(9):
        per = [counts[s][k] for s in SPLITS]
        body.append([k, region_of_class(k)["label"], *per, sum(per)])
    body.append(
        [
            "",
            "all",
            *[sum(counts[s].values()) for s in SPLITS],
            sum(sum(c.values()) for c in counts.values()),
        ]
    )
    return table(header, body)


def _sheets(corpus: Path, sources: list[Path]) -> list[str]:
    """One contact sheet per class (sheets/class-K.jpg), SHEET_PER_CLASS photos spread over
    the sources; returns the Markdown lines linking them."""
    by_class: dict[int, list[Path]] = {k: [] for k in range(9)}
    for src in sources:
        for row in _rows(src):
            by_class[int(row["class"])].append(src / row["file"])
    (corpus / "sheets").mkdir(exist_ok=True)
    lines = []
    rng = np.random.default_rng(0)
    for k, files in by_class.items():
        if not files:
            continue
        pick = sorted(rng.choice(len(files), min(SHEET_PER_CLASS, len(files)), replace=False))
        images = [cv2.imread(str(files[i])) for i in pick]
        contact_sheet([im for im in images if im is not None], corpus / "sheets" / f"class-{k}.jpg")
        label = region_of_class(k)["label"]
        lines.append(f"- [class {k} ({label})](sheets/class-{k}.jpg): {len(files)} photos")
    return lines


def write_corpus_readme(corpus: Path, check: dict[str, Any] | None = None) -> Path:
    """Write corpus/README.md (and corpus/sheets/) from the labelled sources; return the path."""
    splits = read_splits(corpus / "splits.toml")
    sources = corpus_sources(corpus)
    counts: dict[str, Counter[int]] = {s: Counter() for s in SPLITS}
    lines = [INTRO]
    for kind, title in (("boards", "Board sources"), ("negatives", "Sources without the board")):
        group = [s for s in sources if s.parent.name == kind]
        lines += [f"## {title}", ""]
        body = [_source_line(s, splits.get(s.name, "?")) for s in group]
        header = (
            ["source", "repository", "licence", "photos", "kept", "split"]
            if kind == "negatives"
            else ["source", "repository", "licence", "camera", "size", "photos", "labelled",
                  "dropped", "calibration RMS px", "classes 1 / 2 / ... / 8", "split"]
        )  # fmt: skip
        lines += table(header, body) + [""]
        total = sum(int(r[header.index("photos") + 1]) for r in body)
        lines += [f"{len(group)} sources, {total} labelled photos.", ""]
    for s in sources:
        for row in _rows(s):
            counts[splits.get(s.name, "train")][int(row["class"])] += 1
    lines += ["## Photos per region and split", ""] + _region_table(counts) + [""]
    per_split = {sp: sorted(s.name for s in sources if splits.get(s.name) == sp) for sp in SPLITS}
    lines += [f"- **{sp}** sources: {', '.join(f'`{n}`' for n in names)}"
              for sp, names in per_split.items()] + [""]  # fmt: skip
    if check is not None:
        lines += ["## Label check against an independent labeller", ""]
        lines += [check_summary(check), ""]
    lines += ["## Contact sheets", ""] + _sheets(corpus, sources) + [""]
    stamp = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    lines += [f"Written {stamp} on {platform.node()} by `planar-pose corpus report`."]
    path = corpus / "README.md"
    path.write_text("\n".join(lines) + "\n")
    return path


def check_summary(check: dict[str, Any]) -> str:
    """One paragraph: how often the independent labeller agrees on the class, and which
    photos it read (the stored ones, or the full-resolution originals where found)."""
    return (
        "`train.real.crosscheck` (classic corner detector, IPPE PnP refined by OpenCV's "
        "Levenberg-Marquardt, corner-square colours) "
        f"found the board in {check['found']} of {check['count']} labelled photos; the class "
        f"agrees on {pct(check['agreement'])} of them ({check['agree']} / {check['found']}); "
        f"median camera-centre difference {check['median_diff_cm']:.2f} cm."
        + (
            f" Every disagreement is a camera within {check['disagreement_max_boundary_cm']:.1f}"
            " cm of a region boundary (x = 0, y = 0 or the z split)."
            if check.get("disagreement_max_boundary_cm") is not None
            else ""
        )
        + " "
        + _read_sentence(check)
    )


def _read_sentence(check: dict[str, Any]) -> str:
    """Which photos the check read: the stored ones, or the originals and how many of each."""
    read = check.get("read") or {"original": 0, "stored": check["count"]}
    stored = f"stored photos (longer side at most {STORE_MAX_SIDE} px)"
    if not check.get("originals"):
        return (
            f"Photos read: the {read['stored']} {stored}, not the full-resolution originals the "
            "labels were made from (`planar-pose corpus check --originals DIR` reads those)."
        )
    why = "; ".join(f"{reason}: {n}" for reason, n in (check.get("fallbacks") or {}).items())
    where = [
        f"`{name}` {n['stored']}"
        for name, n in (check.get("per_source_read") or {}).items()
        if n["stored"]
    ]
    detail = ", ".join(x for x in (why, ", ".join(where) if len(where) <= 6 else "") if x)
    return (
        f"Photos read: the full-resolution originals (which the labels were made from) of "
        f"{read['original']} photos"
        + (
            f", and the {stored} of the other {read['stored']}" + (f" ({detail})" if detail else "")
            if read["stored"]
            else ""
        )
        + ". The originals are not in the repository: on a clone, `planar-pose corpus check` "
        "reads the stored photos (`--originals DIR` reads a folder of originals)."
    )
