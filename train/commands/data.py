"""CLI of the synthetic data step: `planar-pose data make | grid | sheet | roll`.

Bad arguments exit with code 2, unreadable inputs (profile, texture, data set) with code 1,
always with a one-line message and no stack trace.
"""

from __future__ import annotations

import time
from functools import partial
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.table import Table

from service.core.dataset import SPLITS
from service.core.inputs import SIZE_HELP
from train.commands.common import fail, guard, out, profile_or_exit, split_or_exit

app = typer.Typer(
    name="data",
    help="Synthetic data sets: make one or the 16-set grid, contact sheets, real-photo roll.",
    no_args_is_help=True,
)

ProfileOption = Annotated[
    str, typer.Option(help="Profile name (train/assets/profiles/NAME) or path to a profile.toml.")
]
JitterOption = Annotated[
    bool, typer.Option("--jitter/--no-jitter", help="Photometric jitter (gain, noise, JPEG).")
]
WorkersOption = Annotated[
    int, typer.Option(min=0, help="Worker processes (0 = one per available core).")
]


def _workers(workers: int) -> int:
    from train.synth.generate import default_workers

    return workers or default_workers()


def _make(jobs: list[tuple[Any, Path]], overwrite: bool, workers: int) -> list[dict[str, Any]]:
    """Write the sets with a progress bar; print a summary table."""
    from tqdm import tqdm

    from service.core.dataset import DatasetError
    from train.synth.generate import check_outputs, make_datasets

    guard(lambda: check_outputs([path for _, path in jobs], overwrite), code=2)
    total = sum(spec.count for spec, _ in jobs)
    start = time.perf_counter()
    with tqdm(total=total, desc="rendering", unit="img") as bar:
        try:
            manifests = make_datasets(jobs, overwrite, workers, bar.update)
        except DatasetError as exc:  # existing folder, bad arguments
            raise fail(str(exc), code=2) from None
        except (ValueError, OSError) as exc:  # unreadable background, disk full...
            raise fail(str(exc)) from None
    seconds = time.perf_counter() - start
    table = Table(title=f"{total} images in {seconds:.1f} s ({total / seconds:.0f} img/s)")
    for column in ("data set", "size", *SPLITS, "class counts 0..8"):
        table.add_column(column)
    for (_, path), m in zip(jobs, manifests, strict=True):
        counts = m["counts"]
        table.add_row(
            str(path),
            "x".join(map(str, m["size"])),
            *(str(counts[s]) for s in SPLITS),
            " ".join(map(str, m["class_counts"])),
        )
    out.print(table)
    return manifests


@app.command()
def make(
    out_dir: Annotated[Path, typer.Argument(metavar="OUT", help="Output folder.")],
    variant: Annotated[
        str, typer.Option(help="C (target = object centre), noC (SPEC) or free (anywhere).")
    ] = "noC",
    size: Annotated[int, typer.Option(help=SIZE_HELP)] = 1,
    blur: Annotated[int, typer.Option(help="SPEC blur level 0..3.")] = 0,
    count: Annotated[int, typer.Option(help="Number of images (>= 9).")] = 5000,
    seed: int = 0,
    profile: ProfileOption = "chessboard",
    jitter: JitterOption = True,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing data set in OUT.")] = False,
    workers: WorkersOption = 0,
) -> None:
    """Render one synthetic data set: OUT/images/*.png, OUT/labels.csv, OUT/manifest.json."""
    from train.synth.generate import DatasetSpec

    prof = profile_or_exit(profile)
    spec = guard(lambda: DatasetSpec(variant, size, blur, count, seed, prof, jitter), code=2)
    _make([(spec, out_dir)], overwrite, _workers(workers))


@app.command()
def grid(
    out_root: Annotated[Path, typer.Argument(metavar="OUT_ROOT", help="Folder of the 16 sets.")],
    count: Annotated[int, typer.Option(help="Images per set (>= 9).")] = 5000,
    seed: Annotated[int, typer.Option(help="Set i of the grid gets seed + i.")] = 0,
    profile: ProfileOption = "chessboard",
    jitter: JitterOption = True,
    overwrite: Annotated[bool, typer.Option(help="Replace existing sets.")] = False,
    workers: WorkersOption = 0,
) -> None:
    """Render the 16 SPEC sets {C, noC} x size {1, 2} x blur {0..3} as OUT_ROOT/noC-s1-b0 etc."""
    from train.synth.generate import grid_specs

    prof = profile_or_exit(profile)
    specs = guard(lambda: grid_specs(count, seed, prof, jitter), code=2)
    _make([(spec, out_root / spec.name) for spec in specs], overwrite, _workers(workers))


@app.command()
def sheet(
    dataset: Annotated[Path, typer.Argument(help="Data set folder.")],
    out_png: Annotated[Path, typer.Argument(metavar="OUT.png", help="Contact sheet to write.")],
    per_class: Annotated[int, typer.Option(min=1, max=50, help="Images per class row.")] = 8,
    scale: Annotated[int, typer.Option(min=1, max=8, help="Magnification.")] = 2,
    split: Annotated[str, typer.Option(help="train, val, test or all.")] = "all",
    seed: int = 0,
) -> None:
    """Draw a contact sheet: one row of samples per class, labelled in words."""
    from train.synth.sheet import contact_sheet

    if out_png.suffix.lower() != ".png":
        raise fail(f"the contact sheet must be a .png file, got {out_png}", code=2)
    chosen = split_or_exit(split)
    image = guard(lambda: contact_sheet(dataset, out_png, per_class, scale, chosen, seed))
    out.print(f"[green]wrote[/] {out_png} ({image.shape[1]}x{image.shape[0]})")


@app.command()
def roll(
    labels_csv: Annotated[
        list[Path], typer.Argument(help="Real labels.csv file(s) with OpenCV rvec0..2 columns.")
    ],
) -> None:
    """Measure the camera roll (SPEC 5) of real photographs, to set a profile's roll_deg."""
    import numpy as np

    from train.real.realset import measure_rolls

    for path in labels_csv:
        if not path.is_file():
            raise fail(f"file not found: {path}", code=2)
    rolls = np.concatenate([guard(partial(measure_rolls, p)) for p in labels_csv])
    q = np.percentile(rolls, [0, 5, 50, 95, 100])
    out.print(
        f"{len(rolls)} photos: roll min {q[0]:.1f}, 5 % {q[1]:.1f}, median {q[2]:.1f}, "
        f"95 % {q[3]:.1f}, max {q[4]:.1f} degrees"
    )
