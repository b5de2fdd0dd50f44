"""CLI of the real-photo corpus: `corpus add | frames | charuco | check | sets | report`.

No torch here: labelling is OpenCV.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path
from typing import Annotated, Any

import typer

from service.core.inputs import SIZE_HELP
from service.core.paths import ASSETS_DIR
from train.commands.common import err, fail, guard, out, profile_or_exit, size_or_exit

CORPUS = ASSETS_DIR / "real" / "corpus"
CorpusOption = Annotated[Path, typer.Option("--corpus", help="Corpus folder.")]

app = typer.Typer(
    name="corpus",
    help="The corpus of real photographs: label sources, check labels, build data sets.",
    no_args_is_help=True,
)


def _progress(desc: str) -> Any:
    from tqdm import tqdm

    return lambda paths: tqdm(paths, desc=desc, unit="photo", leave=False)


@app.command()
def add(
    staged: Annotated[list[Path], typer.Argument(help="Staged source folder(s).")],
    negatives: Annotated[
        bool, typer.Option(help="The sources show no board (class 0 photos).")
    ] = False,
    corpus: CorpusOption = CORPUS,
    profile: Annotated[str, typer.Option(help="Object profile.")] = "chessboard",
) -> None:
    """Label staged sources (images/, LICENSE, source.json) into the corpus.

    Board sources: corners, calibration from the source's own views, pose, class; photos
    stored at most 640 px. Negative sources: stored after checking that no board is found.
    """
    from train.real.corpus import import_negatives, label_source

    prof = profile_or_exit(profile)
    kind = "negatives" if negatives else "boards"
    for src in staged:
        dest = corpus / kind / src.name
        step = import_negatives if negatives else label_source
        m = guard(partial(step, src, dest, prof, _progress(src.name)))
        cal = "; ".join(
            f"{c['method']}, RMS {c['rms_px']:.2f} px" for c in m.get("calibration", [])
        )
        out.print(
            f"{src.name}: {m['count']} of {m['photos']} photos kept"
            + (f", class counts {m['class_counts']}" if not negatives else "")
            + (f"; {cal}" if cal else "")
        )
        for reason, n in m.get("failed_by_reason", {}).items():
            err.print(f"  dropped {n}: {reason}")
        if m["count"] == 0:
            raise fail(f"no photo of {src} could be used (see {dest / 'failed.txt'})")


OriginalsOption = Annotated[
    Path | None,
    typer.Option(
        "--originals",
        help="Folder of the full-resolution originals, laid out like staged sources: "
        "DIR/<source>/images/<original> (the labels.csv column `original`). The check reads "
        "them instead of the stored photos; a photo without its original is read as stored.",
    ),
]


@app.command()
def check(
    corpus: CorpusOption = CORPUS,
    profile: Annotated[str, typer.Option(help="Object profile.")] = "chessboard",
    originals: OriginalsOption = None,
    disagreements: Annotated[
        bool, typer.Option("--disagreements", help="List the photos whose classes differ.")
    ] = False,
) -> None:
    """Relabel every board photo with an independent labeller; print the class agreement."""
    from train.real.corpus_report import check_summary

    _originals_or_exit(originals)
    stats = guard(lambda: run_check(corpus, profile_or_exit(profile), originals))
    for name, (agree, found) in stats["per_source"].items():
        read = stats["per_source_read"][name]
        note = f" (read {read['original']} originals, {read['stored']} stored)" if originals else ""
        out.print(f"{name}: {agree} / {found} agree{note}")
    if disagreements:
        for d in stats["disagreements"]:
            diff = "" if d["centre_diff_cm"] is None else f"{d['centre_diff_cm']:.1f}"
            out.print(
                f"  {d['source']}/{d['file']} ({d['read']}): class {d['class']}, independent "
                f"{d['independent_class']}, centre difference {diff} cm, "
                f"{d['boundary_cm']:.1f} cm from a region boundary",
                soft_wrap=True,
            )
    for reason, n in stats["fallbacks"].items():
        err.print(f"  read as stored, {n} photos: {reason}")
    out.print(check_summary(stats))


def _originals_or_exit(originals: Path | None) -> None:
    if originals is None:
        return
    if not originals.exists():
        raise fail(f"--originals folder not found: {originals}")
    if not originals.is_dir():
        raise fail(f"--originals is not a folder: {originals}")


def run_check(corpus: Path, prof: Any, originals: Path | None = None) -> dict[str, Any]:
    """Independent labeller over the corpus's board sources: agreement counts.

    With `originals` (see `train.real.crosscheck`), the full-resolution originals are read
    where found; `read` counts the photos read as "original" and as "stored"."""
    from collections import Counter

    import numpy as np

    from service.core.dataset import corpus_sources
    from train.real.crosscheck import crosscheck_folder
    from train.real.label import chessboard_pattern

    pattern = chessboard_pattern(prof)
    if pattern is None:
        raise ValueError(f"profile {prof.name!r} is not a chessboard")
    per_source: dict[str, tuple[int, int]] = {}
    per_source_read: dict[str, dict[str, int]] = {}
    diffs: list[float] = []
    disagree: list[dict[str, Any]] = []
    fallbacks: Counter[str] = Counter()
    count = 0
    for src in corpus_sources(corpus):
        if src.parent.name != "boards":
            continue
        rows = crosscheck_folder(src, pattern, float(prof.geometry.z_split_cm), originals)
        found = [r for r in rows if r["independent_class"] is not None]
        agree = sum(r["class"] == r["independent_class"] for r in found)
        per_source[src.name] = (agree, len(found))
        read = Counter(r["read"] for r in rows)
        per_source_read[src.name] = {"original": read["original"], "stored": read["stored"]}
        fallbacks.update(r["fallback"] for r in rows if r["fallback"])
        diffs += [r["centre_diff_cm"] for r in found]
        disagree += [
            {"source": src.name, **r} for r in found if r["class"] != r["independent_class"]
        ]
        count += len(rows)
    found_all = sum(f for _, f in per_source.values())
    agree_all = sum(a for a, _ in per_source.values())
    return {
        "count": count,
        "found": found_all,
        "agree": agree_all,
        "agreement": agree_all / found_all if found_all else None,
        "median_diff_cm": float(np.median(diffs)) if diffs else float("nan"),
        "disagreement_max_boundary_cm": max((d["boundary_cm"] for d in disagree), default=None),
        "per_source": per_source,
        "originals": originals is not None,
        "read": {k: sum(r[k] for r in per_source_read.values()) for k in ("original", "stored")},
        "per_source_read": per_source_read,
        "fallbacks": dict(fallbacks),
        "disagreements": disagree,
    }


@app.command()
def frames(
    video: Annotated[Path, typer.Argument(help="A video file.")],
    out_dir: Annotated[Path, typer.Argument(help="Folder for the frames (PNG).")],
    every: Annotated[int, typer.Option(min=1, help="Keep every N-th frame.")] = 1,
) -> None:
    """Extract a video's frames as lossless PNGs, to stage them as a source (then run the
    held-out guard on the folder before labelling it)."""
    from train.real.charuco import extract_frames

    if not video.is_file():
        raise fail(f"video not found: {video}")
    written = guard(lambda: extract_frames(video, out_dir, every))
    out.print(f"[green]wrote[/] {len(written)} frames to {out_dir}")


@app.command()
def charuco(
    staged: Annotated[Path, typer.Argument(help="Staged source (images/, LICENSE, source.json).")],
    dest: Annotated[Path, typer.Argument(help="The labelled source folder to write.")],
    camera_array: Annotated[
        Path, typer.Option(help="caliscope camera_array.toml with the camera's calibration.")
    ],
    cam: Annotated[int, typer.Option(help="The camera's id in that file.")],
    profile: Annotated[str, typer.Option(help="Profile with a [charuco] table.")] = "charuco",
) -> None:
    """Label the frames of one calibrated camera with the ChArUco detector (train/real/charuco)."""
    from train.real.charuco import label_video_source, read_camera_array

    prof = profile_or_exit(profile)
    cameras = guard(lambda: read_camera_array(camera_array))
    if cam not in cameras:
        raise fail(f"no camera {cam} in {camera_array} (it has {sorted(cameras)})", code=2)
    m = guard(lambda: label_video_source(staged, dest, prof, cameras[cam], _progress(staged.name)))
    check = m["texture_check"]
    out.print(
        f"{staged.name}: {m['count']} of {m['photos']} frames labelled, class counts "
        f"{m['class_counts']}; texture check: {check['found']} posed, "
        f"{check['class_agrees']} agree on the class"
    )


@app.command()
def sets(
    out_dir: Annotated[Path, typer.Argument(help="Folder for the data sets real-s{S}-b{B}.")],
    size: Annotated[list[int], typer.Option(help=SIZE_HELP)] = [1, 2],  # noqa: B006
    blur: Annotated[list[int], typer.Option(help="SPEC blur levels.")] = [0, 1, 2, 3],  # noqa: B006
    corpus: CorpusOption = CORPUS,
    profile: Annotated[str, typer.Option(help="Object profile (z split).")] = "chessboard",
) -> None:
    """Build the real data sets (one per size and blur level), split by source."""
    from train.real.realset import build_corpus_dataset

    for s in size:
        size_or_exit(s)
    if any(not 0 <= b <= 3 for b in blur):
        raise fail(f"--blur must be in 0..3, got {blur}", code=2)
    profile_or_exit(profile)
    for s in size:
        for b in blur:
            dest = out_dir / f"real-s{s}-b{b}"
            m = guard(partial(build_corpus_dataset, corpus, dest, s, b, profile))
            out.print(f"[green]wrote[/] {dest}: {m['counts']}, classes {m['class_counts']}")


@app.command()
def report(
    corpus: CorpusOption = CORPUS,
    profile: Annotated[str, typer.Option(help="Object profile.")] = "chessboard",
    with_check: Annotated[bool, typer.Option("--check/--no-check", help="Run `check`.")] = True,
    originals: OriginalsOption = None,
) -> None:
    """Write the corpus README (tables per source, region and split) and contact sheets."""
    from train.real.corpus_report import write_corpus_readme

    prof = profile_or_exit(profile)
    _originals_or_exit(originals)
    stats = guard(lambda: run_check(corpus, prof, originals)) if with_check else None
    path = guard(lambda: write_corpus_readme(corpus, stats))
    out.print(f"[green]wrote[/] {path}")
