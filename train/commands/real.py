"""CLI of the real-photo and baseline steps: `label`, `baseline` and `compare`.

No torch here: the baseline is OpenCV and the comparison runs the CNN through onnxruntime.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.table import Table

from train.commands.common import err, fail, guard, out, profile_or_exit, split_or_exit


def label(
    images_dir: Annotated[Path, typer.Argument(help="Folder of photographs to label.")],
    out_dir: Annotated[Path, typer.Argument(help="Output data set folder.")],
    profile: Annotated[str, typer.Option(help="Object profile name or folder.")] = "chessboard",
    corners: Annotated[
        Path | None,
        typer.Option(help="CSV of clicked corners (file, corner_x0, corner_y0, ... corner_y3)."),
    ] = None,
    calibration: Annotated[
        Path | None, typer.Option(help="Calibration JSON (K, distortion); default: a guess.")
    ] = None,
    truth: Annotated[
        Path | None,
        typer.Option(help="Ground-truth labels.csv (file, cam_x, cam_y, cam_z) to check against."),
    ] = None,
    seed: Annotated[int, typer.Option(help="Seed of the train/val/test split.")] = 0,
) -> None:
    """Label photographs: corners (found or clicked) -> DLT homography -> pose, refined on the
    reprojection error -> class.

    Writes labels.csv, manifest.json, failed.txt, the images and overlays/ to check by eye.
    """
    from tqdm import tqdm

    from train.real.calibration import Calibration
    from train.real.label import compare_to_truth, label_folder, list_images, read_corner_csv

    guard(lambda: list_images(images_dir))
    prof = profile_or_exit(profile)
    cal = guard(lambda: Calibration.load(calibration)) if calibration else None
    clicked = guard(lambda: read_corner_csv(corners)) if corners else None
    if truth is not None and not truth.is_file():
        raise fail(f"ground truth not found: {truth}")

    def progress(paths: Iterable[Path]) -> Iterable[Path]:
        return tqdm(paths, desc="labelling", unit="image")

    manifest = guard(lambda: label_folder(images_dir, out_dir, prof, cal, clicked, seed, progress))
    out.print(
        f"[green]labelled[/] {manifest['count']} image(s) into {out_dir} "
        f"({', '.join(f'{m}: {n}' for m, n in manifest['methods'].items()) or 'none'}); "
        f"class counts {manifest['class_counts']}"
    )
    if manifest["mean_reproj_rms_px"] is not None:
        out.print(f"mean reprojection RMS {manifest['mean_reproj_rms_px']:.3f} px")
    if manifest["failed_files"]:
        err.print(f"[yellow]{len(manifest['failed_files'])} image(s) not labelled[/] (failed.txt):")
        for line in manifest["failed_files"]:
            err.print(f"  {line}")
    out.print(f"check the labels by eye in {out_dir / 'overlays'}")
    if truth is not None:
        z_split = float(prof.geometry.z_split_cm)
        check = guard(lambda: compare_to_truth(out_dir, truth, z_split))
        out.print(
            f"against {truth}: {check['count']} images, camera centre error mean "
            f"{check['centre_error_cm_mean']:.3f} cm, max {check['centre_error_cm_max']:.3f} cm, "
            f"class agreement {100 * check['class_agreement']:.1f} %"
        )
    if manifest["count"] == 0:
        raise fail("no image could be labelled")


def baseline(
    datasets: Annotated[list[Path], typer.Argument(help="Data set folder(s).")],
    out_dir: Annotated[Path, typer.Option("--out", help="Folder for metrics.json and plots.")],
    features: Annotated[str, typer.Option(help="sift, orb or both.")] = "sift",
    split: Annotated[str, typer.Option(help="Split to measure: train, val, test or all.")] = "test",
    tune: Annotated[
        bool, typer.Option(help="Tune ratio / RANSAC thresholds on each set's val split.")
    ] = True,
    profile: Annotated[
        str | None, typer.Option(help="Profile name or folder (default: the data set's own).")
    ] = None,
    limit: Annotated[
        int, typer.Option(min=0, help="Use at most N images per split (0 = all).")
    ] = 0,
) -> None:
    """Feature baseline (SIFT/ORB, RANSAC, IPPE PnP) on data set(s): metrics.json + report."""
    from train.compare.baseline import FEATURE_CHOICES, BaselineConfig
    from train.compare.peers import run_baseline_on
    from train.network.report import write_report

    if features not in FEATURE_CHOICES:
        raise fail(f"--features must be one of {', '.join(FEATURE_CHOICES)}", code=2)
    split_or_exit(split)
    for path in datasets:
        if not (path / "labels.csv").is_file():
            raise fail(f"not a data set (no labels.csv): {path}")

    def body() -> Path:
        name = f"baseline-{features}"
        results: dict[str, dict[str, dict[str, Any]]] = {name: {}}
        notes = [
            f"Split `{split}`. Written by `planar-pose baseline`; features {features}, "
            "ratio test, RANSAC homography, IPPE PnP; no homography = class 0."
        ]
        for ds in datasets:
            metrics, info = run_baseline_on(
                ds, BaselineConfig(features=features), split, tune, profile, limit, verbose=True
            )
            results[name][ds.name] = metrics
            tuned = info.get("tuning")
            chosen = (
                f"tuned on val: ratio {tuned['chosen']['ratio']}, RANSAC "
                f"{tuned['chosen']['ransac_px']} px (val accuracy "
                f"{100 * tuned['val_accuracy']:.1f} %)"
                if tuned
                else "default thresholds"
            )
            notes.append(
                f"`{ds.name}`: {chosen}; no-pose reasons: "
                + (", ".join(f"{k} x{v}" for k, v in info["failures"].items()) or "none")
            )
            out.print(
                f"{ds.name}: accuracy {100 * metrics['accuracy']:.2f} %, "
                f"{metrics['ms_per_image']:.1f} ms / image; {chosen}"
            )
        return write_report(results, out_dir, None, "Feature baseline", notes)

    report = guard(body)
    out.print(f"[green]done[/]: {out_dir / 'metrics.json'}, {report}")


def compare(
    models: Annotated[
        list[Path],
        typer.Option("--models", help="ONNX model to compare (repeat the option for more)."),
    ],
    datasets: Annotated[
        list[Path], typer.Option("--datasets", help="Data set folder (repeat the option for more).")
    ],
    markdown: Annotated[Path, typer.Option("--out", help="Markdown report.")] = Path(
        "docs/comparison.md"
    ),
    features: Annotated[
        str | None, typer.Option(help="Default feature peer: sift, orb or both (default sift).")
    ] = None,
    peer: Annotated[
        list[str] | None,
        typer.Option(
            "--peer",
            help="Classical method to compare with: sift, orb, both or chessboard (repeat for "
            "more; default: chessboard, used on chessboard profiles only, plus sift).",
        ),
    ] = None,
    split: Annotated[str, typer.Option(help="Split measured.")] = "test",
    photos: Annotated[
        Path | None,
        typer.Option(
            help="Folder of full-size real photos + labels.csv for whole/sliding/proposals."
        ),
    ] = None,
    detection_dataset: Annotated[
        list[Path] | None,
        typer.Option("--detection-dataset", help="Synthetic set(s) for whole/sliding/proposals."),
    ] = None,
    limit: Annotated[int, typer.Option(min=0, help="At most N images per split (0 = all).")] = 0,
    tune: Annotated[bool, typer.Option(help="Tune the baseline on each val split.")] = True,
    resize: Annotated[
        bool,
        typer.Option(
            help="Also run each model on the data sets of other image sizes, resized to its "
            "input as the service resizes an upload."
        ),
    ] = False,
    given_fx: Annotated[
        bool,
        typer.Option(
            help="Also run each model that takes a focal length given the fx of the camera "
            "the chessboard detector is given (method '<model> + fx')."
        ),
    ] = True,
) -> None:
    """CNN (onnxruntime) vs the classical peers, per data set, in one run: Markdown + plots."""
    from train.compare.run import CompareConfig, run_comparison

    _check_compare_options(features, peer or [], split)
    _check_compare_files(models, [*datasets, *(detection_dataset or [])], photos)
    config = CompareConfig(
        models=models,
        datasets=datasets,
        markdown=markdown,
        features=features or "sift",
        split=split,
        photos=photos,
        detection_datasets=detection_dataset or [],
        limit=limit,
        tune=tune,
        peers=list(peer or []),
        resize=resize,
        given_fx=given_fx,
    )
    summary = guard(lambda: run_comparison(config))
    table = Table(title="accuracy %  (ms / image)")
    for column in ["data set", *summary["columns"]]:
        table.add_column(column)
    for row in summary["rows"]:
        table.add_row(*row)
    out.print(table)
    out.print(f"[green]wrote[/] {markdown} and {json.dumps(summary['files'])}")


def _check_compare_options(features: str | None, peers: list[str], split: str) -> None:
    """`compare`'s --features, --peer and --split, or a usage error (exit 2)."""
    from train.compare.baseline import FEATURE_CHOICES
    from train.compare.peers import PEER_CHOICES

    if features is not None and features not in FEATURE_CHOICES:
        raise fail(f"--features must be one of {', '.join(FEATURE_CHOICES)}", code=2)
    if features is not None and peers:
        raise fail("give either --peer or --features (the default peers' features)", code=2)
    for kind in peers:
        if kind not in PEER_CHOICES:
            raise fail(f"--peer must be one of {', '.join(PEER_CHOICES)}, got {kind!r}", code=2)
    split_or_exit(split)


def _check_compare_files(models: list[Path], datasets: list[Path], photos: Path | None) -> None:
    """`compare`'s ONNX models, data sets and photo folder exist, or an error (exit 1)."""
    for path in models:
        if path.suffix != ".onnx" or not path.is_file():
            raise fail(f"not an ONNX model file: {path}")
    for path in datasets:
        if not (path / "labels.csv").is_file():
            raise fail(f"not a data set (no labels.csv): {path}")
    if photos is not None and not (photos / "labels.csv").is_file():
        raise fail(f"no labels.csv in the photo folder {photos}")


#: The real-photo commands; `train.cli` merges them into the `planar-pose` app.
app = typer.Typer()
app.command()(label)
app.command()(baseline)
app.command()(compare)
