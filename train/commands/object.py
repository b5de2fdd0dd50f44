"""CLI of a user's own object: `object new | train`.

    planar-pose object new poster --texture poster.jpg --size 42 59.4
    planar-pose object train poster

No torch at import time (the command modules' rule); `train` imports it when it runs.
"""

from __future__ import annotations

import re
import tempfile
import time
from pathlib import Path
from typing import Annotated

import cv2
import typer

from service.core.paths import DEFAULT_MODEL_DIR, REPO_ROOT
from service.core.profile import PROFILES_DIR, Profile, ProfileError, write_profile
from service.core.regions import Z_SPLIT_CM
from train.commands.common import fail, guard, out, profile_or_exit

app = typer.Typer(
    name="object",
    help="Your own planar object: a profile from its picture, then its whole training recipe.",
    no_args_is_help=True,
)
#: Profile names: usable in a folder, a file and a URL (`service.pipeline.registry.NAME_PATTERN`).
NAME = re.compile(r"[a-z0-9][a-z0-9-]*")
#: The generic corner network's weights (`train.network.zeroshot.GENERIC_WEIGHTS`: not
#: imported here, the command modules import no torch).
GENERIC_WEIGHTS = REPO_ROOT / "models" / "generic" / "corners-any-160x120.npz"
#: Renders in the sample sheet of `new`.
SHEET_COUNT = 90


@app.command()
def new(
    name: Annotated[str, typer.Argument(help="Object name: lower-case letters, digits, '-'.")],
    texture: Annotated[Path, typer.Option(help="Front-on picture of the object, cropped to it.")],
    size: Annotated[
        tuple[float, float], typer.Option(help="Width and height of the object in cm.")
    ],
    profiles: Annotated[Path, typer.Option(help="Folder of profiles.")] = PROFILES_DIR,
    z_split: Annotated[float, typer.Option(help="Near / far split, cm.")] = Z_SPLIT_CM,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing profile.")] = False,
    zero_shot: Annotated[
        bool, typer.Option(help="Serve it at once: the generic network with its picture.")
    ] = True,
    generic: Annotated[
        Path, typer.Option(help="The generic corner network's weights (corners-any).")
    ] = GENERIC_WEIGHTS,
    models: Annotated[Path, typer.Option(help="Served model folder.")] = DEFAULT_MODEL_DIR,
    run: Annotated[
        Path | None, typer.Option(help="Folder of the zero-shot renders (default runs/NAME).")
    ] = None,
    eval_count: Annotated[
        int, typer.Option(min=9, help="Renders per blur level the zero-shot model is measured on.")
    ] = 90,
    threshold_count: Annotated[
        int | None,
        typer.Option(
            min=36,
            help="Renders (classes 0-8, blur 0-3) its presence threshold is measured on "
            "(default: the zero-shot recipe's; fewer: faster, a less certain threshold).",
        ),
    ] = None,
) -> None:
    """Write a validated profile (profile.toml + texture.png), a sheet of sample renders and
    (with the generic network) a zero-shot model in the model folder."""
    from train.synth.generate import DatasetSpec, make_dataset
    from train.synth.sheet import contact_sheet

    start = time.monotonic()

    if not NAME.fullmatch(name):
        raise fail(f"name {name!r}: use lower-case letters, digits and '-'", code=2)
    folder = profiles / name
    if folder.exists() and not overwrite:
        raise fail(f"profile {folder} exists (--overwrite replaces it)")
    bgr = cv2.imread(str(texture), cv2.IMREAD_COLOR)
    if bgr is None:
        raise fail(f"not a readable image: {texture}")
    rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    try:
        profile = write_profile(folder, name, rgb, size[0], size[1], z_split)
    except ProfileError as exc:
        raise fail(str(exc)) from None
    sheet = folder / "samples.jpg"
    with tempfile.TemporaryDirectory() as tmp:
        samples = Path(tmp) / "samples"
        guard(lambda: make_dataset(samples, DatasetSpec("free", 2, 0, SHEET_COUNT, 0, profile)))
        guard(lambda: contact_sheet(samples, sheet, per_class=8, scale=1))
    out.print(f"[green]wrote[/] {folder / 'profile.toml'} and {sheet} (look at the renders)")
    if zero_shot and generic.is_file():
        folder = run or Path("runs") / profile.name
        _zero_shot(profile, generic, models, folder, eval_count, threshold_count, start)
    elif zero_shot:
        out.print(f"[yellow]no generic network at {generic}[/]: no zero-shot model")
    out.print(f"next: planar-pose object train {name}")


def _zero_shot(
    profile: Profile,
    generic: Path,
    models: Path,
    run: Path,
    eval_count: int,
    threshold_count: int | None,
    start: float,
) -> None:
    """Serve the object at once: the generic network with its picture (`zero_shot_model`),
    its renders in `run`, measured on `eval_count` renders per blur level, its presence
    threshold on `threshold_count` renders (None: the recipe's)."""
    from train.network.pipeline import THRESHOLD_COUNT, zero_shot_model

    path, card = guard(
        lambda: zero_shot_model(
            profile, run, models, generic, out.print, eval_count, threshold_count or THRESHOLD_COUNT
        )
    )
    info = card["zero_shot"]
    if info["backgrounds_excluded"]:
        shown = ", ".join(info["backgrounds_excluded"])
        out.print(f"left out of its renders (they show its texture, by matching): {shown}")
    seconds = time.monotonic() - start
    out.print(f"[green]wrote[/] {path} (zero-shot, {seconds:.0f} s); served as ?model={path.stem}")
    for ds, acc in card["accuracy"].items():
        out.print(
            f"  {ds} ({acc['count']} renders): {100 * acc['accuracy']:.1f} % right, "
            f"class 0 {100 * acc['class0_accuracy']:.1f} %"
        )


@app.command("train")
def train_command(
    name: Annotated[str, typer.Argument(help="Profile name or path.")],
    run: Annotated[Path | None, typer.Option(help="Run folder (default runs/NAME).")] = None,
    models: Annotated[Path, typer.Option(help="Served model folder.")] = DEFAULT_MODEL_DIR,
    real: Annotated[
        list[Path] | None,
        typer.Option(
            help="Real data sets of the object (planar-pose corpus sets): select on "
            "their val split, fine-tune on their train split."
        ),
    ] = None,  # fmt: skip
    count: Annotated[
        int | None, typer.Option(min=90, help="Training renders (default 22000; scratch 20000).")
    ] = None,
    eval_count: Annotated[int, typer.Option(min=45, help="Renders per evaluation set.")] = 1000,
    epochs: Annotated[
        int | None, typer.Option(min=1, help="Epochs on the renders (default 8; scratch 10).")
    ] = None,
    generic: Annotated[
        Path, typer.Option(help="The generic corner network to fine-tune from.")
    ] = GENERIC_WEIGHTS,
    scratch: Annotated[
        bool, typer.Option(help="Train the corner network from scratch, not the generic one.")
    ] = False,
    fine_tune_epochs: Annotated[int, typer.Option(min=1, help="Epochs on real data.")] = 6,
    batch_size: Annotated[int, typer.Option(min=2, help="Images per batch.")] = 64,
    lr: Annotated[
        float | None,
        typer.Option(min=1e-6, max=1.0, help="Peak learning rate (default 1e-3; scratch 2e-3)."),
    ] = None,
    threads: Annotated[int, typer.Option(min=0, help="Torch threads, 0 = default.")] = 0,
    workers: Annotated[int, typer.Option(min=1, help="Render processes.")] = 1,
    device: Annotated[
        str, typer.Option(help="auto (a CUDA GPU where torch sees one), cuda or cpu.")
    ] = "auto",
    bf16: Annotated[
        bool | None,
        typer.Option(help="bfloat16 autocast (default: where the device computes it natively)."),
    ] = None,
) -> None:
    """Render, train, export and measure the object's corner model; resumable (run it again)."""
    from train.network.fit import native_bf16, training_device
    from train.network.pipeline import ObjectRecipe, train_object

    if device not in ("auto", "cuda", "cpu"):
        raise fail(f"--device must be auto, cuda or cpu, got {device!r}", code=2)
    guard(lambda: training_device(device), code=2)  # before any render: no GPU is a clear error
    profile = profile_or_exit(name)
    for path in real or []:
        if not (path / "labels.csv").is_file():
            raise fail(f"not a data set (no labels.csv): {path}")
    start_from = None if scratch else generic
    if start_from is not None and not start_from.is_file():
        out.print(f"[yellow]no generic network at {generic}[/]: training from scratch")
        start_from = None
    fine = start_from is not None
    peak = lr or (0.001 if fine else 0.002)
    recipe = ObjectRecipe(
        train_count=count or (22000 if fine else 20000), eval_count=eval_count,
        epochs=epochs or (8 if fine else 10), generic=start_from, lr=peak,
        fine_tune_epochs=fine_tune_epochs, batch_size=batch_size, threads=threads,
        bf16=native_bf16(device) if bf16 is None else bf16, workers=workers, device=device,
    )  # fmt: skip
    start = time.monotonic()
    run_dir = run or Path("runs") / profile.name
    path, card = guard(lambda: train_object(profile, run_dir, models, recipe, real, out.print))
    minutes = (time.monotonic() - start) / 60
    out.print(
        f"[green]wrote[/] {path} in {minutes:.1f} min (this run); served as ?model={path.stem}"
    )
    for ds, acc in [*card["accuracy"].items(), *card.get("accuracy_val", {}).items()]:
        out.print(f"  {ds} ({acc['split']}, {acc['count']} images): {100 * acc['accuracy']:.2f} %")
