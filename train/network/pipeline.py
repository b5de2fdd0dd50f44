"""The whole recipe of one object, from its profile to a served model: `train_object`.

    renders     free-target renders of the profile at 160x120 for training (all four blur
                levels mixed by the augmentation), and one evaluation set per blur level
                with other seeds (other backgrounds and camera draws)
    stage 1     the corner network (`corners`) on the renders; with real data sets of the
                object (`real`, made by `planar-pose corpus sets`), the best epoch is picked on
                their val split, else on the renders' val split
    stage 2     with real data sets: fine-tuned on their train split mixed with the renders,
                from stage 1's best epoch at a lower learning rate
    export      models/<name>-corners-160x120.onnx with its card, measured on the evaluation
                renders' test split (and the real test split)

Every step leaves its output in the run folder and is skipped when it is there, and a stage
stopped midway continues from its last epoch: running it again resumes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from service.core.blur import BLUR_LEVELS
from service.core.dataset import MANIFEST_FILE
from service.core.inputs import SIZES
from service.core.profile import Profile
from train.network.config import FitConfig
from train.network.export import export
from train.network.fit import fit
from train.synth.generate import DatasetSpec, make_datasets

#: Seeds of the renders: training, then evaluation set b (+ b).
TRAIN_SEED, EVAL_SEED = 601, 6020


@dataclass(frozen=True)
class ObjectRecipe:
    """The budget of `train_object`: renders, epochs, threads, precision."""

    train_count: int = 20000
    eval_count: int = 1000
    epochs: int = 10
    fine_tune_epochs: int = 6
    batch_size: int = 64
    threads: int = 0
    bf16: bool = False
    workers: int = 1
    device: str = "auto"


def model_name(profile: Profile) -> str:
    """The served name of the object's corner model: object, network, input size."""
    w, h = SIZES[2]
    return f"{profile.name}-corners-{w}x{h}"


def train_object(
    profile: Profile,
    run: Path,
    models: Path,
    recipe: ObjectRecipe,
    real: list[Path] | None = None,
    say: Callable[[str], None] = print,
) -> tuple[Path, dict[str, Any]]:
    """Run (or resume) the object's recipe in the folder `run`; write the model to `models`
    -> (its ONNX path, its card)."""
    data = run / "data"
    train_set = data / "train-free-s2"
    evals = [data / f"free-s2-b{b}" for b in BLUR_LEVELS]
    jobs = [(DatasetSpec("free", 2, 0, recipe.train_count, TRAIN_SEED, profile), train_set)]
    jobs += [
        (DatasetSpec("free", 2, b, recipe.eval_count, EVAL_SEED + b, profile), path)
        for b, path in zip(BLUR_LEVELS, evals, strict=True)
    ]
    todo = [(spec, out) for spec, out in jobs if not (out / MANIFEST_FILE).is_file()]
    if todo:
        say(f"renders: {len(todo)} data set(s) in {data}")
        make_datasets(todo, overwrite=True, workers=recipe.workers)
    real = real or []
    common: dict[str, Any] = {
        "arch": "corners", "batch_size": recipe.batch_size, "optimizer": "adam",
        "weight_decay": 0.0, "schedule": "cosine", "patience": 0, "threads": recipe.threads,
        "device": recipe.device,
        "bf16": recipe.bf16, "corner_weight": 5.0, "corner_beta": 0.01, "squash": 0.25,
        "extra": {"rebuild": [f"planar-pose object train {profile.name}"]},
    }  # fmt: skip
    stage1 = run / "runs" / "renders"
    best = _stage(
        FitConfig(
            datasets=[train_set],
            out=stage1,
            epochs=recipe.epochs,
            lr=0.002,
            seed=41,
            select=real,
            **common,
        ),  # fmt: skip
        say,
    )
    if real:
        best = _stage(
            FitConfig(
                datasets=[train_set, *real],
                out=run / "runs" / "real",
                epochs=recipe.fine_tune_epochs,
                lr=0.0003,
                seed=42,
                init=best,
                select=real,
                repeat=[1] + [8] * len(real),
                **common | {"squash": 0.5},
            ),  # fmt: skip
            say,
        )
    name = model_name(profile)
    say(f"export: {models / name}.onnx, measured on {', '.join(p.name for p in evals + real)}")
    notes = (
        f"The corner network of profile {profile.name}, made by `planar-pose object train` "
        f"({recipe.epochs} epochs on {recipe.train_count} renders"
        + (f", then {recipe.fine_tune_epochs} on the real train frames)" if real else ")")
        + "; the half turn is read from the texture (train/network/pattern.py)."
    )
    return export(best, name, models, [*evals, *real], "test", "1.0.0", notes, real or None)


def _stage(config: FitConfig, say: Callable[[str], None]) -> Path:
    """Train one stage unless its run folder is done; resume it if it stopped -> best.pt."""
    done = config.out / "done"
    if not done.is_file():
        resume = (config.out / "last.pt").is_file()
        say(f"{'resume' if resume else 'train'}: {config.out} ({config.epochs} epochs)")
        summary = fit(config, resume=resume)
        best = summary["best"]
        say(f"  best epoch {best['epoch']}: val {100 * best['val_accuracy']:.1f} %")
        done.write_text("done\n")
    return config.out / "best.pt"
