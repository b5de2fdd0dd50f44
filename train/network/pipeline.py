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

Every step leaves its output in the run folder and is skipped when it is there (the export
when the model file is the one the run wrote from its best checkpoint), and a stage stopped
midway continues from its last epoch: running it again resumes.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from service.core.blur import BLUR_LEVELS
from service.core.dataset import MANIFEST_FILE
from service.core.inputs import SIZES
from service.core.profile import Profile
from train.network.config import FitConfig
from train.network.export import export, repo_path, with_card
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
    #: the generic corner network's weights to fine-tune from (`zero_shot_checkpoint`);
    #: None: the corner network from scratch
    generic: Path | None = None
    lr: float = 0.002


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
    # fine-tuning trains on every render, selected on the evaluation sets' val split (blur
    # 0-3); from scratch, the shipped models' recipe (60 / 20 / 20 splits, their val split)
    fine = recipe.generic is not None
    train_spec = DatasetSpec("free", 2, 0, recipe.train_count, TRAIN_SEED, profile, all_train=fine)
    jobs = [(train_spec, train_set)]
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
    init = None
    if recipe.generic is not None:
        init = run / "zero-shot.pt"
        if not init.is_file():
            say(f"from the generic network {recipe.generic}: {init}")
            zero_shot_checkpoint(profile, run, recipe.generic)
        common |= {"arch": "corners-any"}
    stage1 = FitConfig(
        datasets=[train_set], out=run / "runs" / "renders", epochs=recipe.epochs, lr=recipe.lr,
        seed=41, select=real or (evals if fine else []), init=init, **common,
    )  # fmt: skip
    if not (stage1.out / "done").is_file():
        say(expected_duration(stage1, recipe))
    best = _stage(stage1, say)
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
    exported = _exported(run, best, models / f"{name}.onnx")
    if exported is not None:
        say(f"export: {models / name}.onnx is up to date (from {best})")
        return exported
    say(f"export: {models / name}.onnx, measured on {', '.join(p.name for p in evals + real)}")
    start = "fine-tuned from the generic network (corners-any), " if init else ""
    notes = (
        f"The corner network of profile {profile.name}, made by `planar-pose object train` "
        f"({start}{recipe.epochs} epochs on {recipe.train_count} renders"
        + (f", then {recipe.fine_tune_epochs} on the real train frames)" if real else ")")
        + "; the half turn is read from the texture (train/network/pattern.py)."
    )
    path, card = export(best, name, models, [*evals, *real], "test", "1.0.0", notes, real or None)
    marker = {"checkpoint": _digest(best), "onnx": str(path.resolve()), "model": _digest(path)}
    (run / EXPORTED).write_text(json.dumps(marker, indent=1) + "\n")
    return path, card


#: The run folder's record of its last export: the checkpoint's and the model's digests.
EXPORTED = "exported.json"


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _exported(run: Path, best: Path, onnx: Path) -> tuple[Path, dict[str, Any]] | None:
    """(onnx, its card) when the run's last export wrote `onnx` from the checkpoint `best`
    as they both are now, else None (the model is exported again)."""
    try:
        marker = json.loads((run / EXPORTED).read_text())
        card = json.loads(onnx.with_suffix(".json").read_text())
        same = (
            marker["onnx"] == str(onnx.resolve())
            and marker["checkpoint"] == _digest(best)
            and marker["model"] == _digest(onnx)
        )
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return (onnx, card) if same else None


def expected_duration(config: FitConfig, recipe: ObjectRecipe, steps: int = 4) -> str:
    """What the stage will take on this machine, measured from its first steps: `steps`
    training steps of the stage's network on a batch of its images (the first one not
    counted) times the batches of its epochs -> a sentence that says so, and how to make it
    shorter."""
    import time

    import torch

    from train.network.fit import Augmenter, _initial_network, load_split

    if config.threads:
        torch.set_num_threads(config.threads)
    train, info = load_split(config.datasets, "train")
    size = (train.images.shape[2], train.images.shape[1])
    net, _ = _initial_network(config, train, size, info[0].get("profile"))
    net.train()
    opt = torch.optim.Adam(net.parameters(), lr=0.0)  # timing only: the weights stay
    rng = np.random.default_rng(0)
    n = min(config.batch_size, len(train.labels))
    times = []
    for _ in range(steps):
        t0 = time.perf_counter()
        x, _ = Augmenter(size)(train.images[:n], train.blur[:n], rng, train.corners[:n])
        out = net(x)
        loss = out[0].sum() if isinstance(out, tuple) else out.sum()
        opt.zero_grad()
        loss.backward()
        opt.step()
        times.append((time.perf_counter() - t0) / n)
    per_image = float(np.mean(times[1:]))
    minutes = per_image * len(train.labels) * config.epochs / 60
    took = f"about {minutes:.0f} min" if minutes >= 1 else "under a minute"
    return (
        f"expected: {took} of training on this machine ({config.epochs} "
        f"epochs x {len(train.labels)} images at {1000 * per_image:.0f} ms / image, measured "
        f"on {steps - 1} steps; plus the evaluation after each epoch); shorter: fewer --epochs "
        f"or --count (now {recipe.train_count})"
    )


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


#: Seeds and sizes of `zero_shot_model`'s renders: the threshold set (classes 0-8, blur 0-3
#: mixed by set), and one evaluation set per blur level (other cameras and backgrounds).
THRESHOLD_SEED, ZERO_SHOT_EVAL_SEED = 7001, 7100
THRESHOLD_COUNT, ZERO_SHOT_EVAL_COUNT = 432, 90


def zero_shot_checkpoint(
    profile: Profile, run: Path, generic: Path, count: int = THRESHOLD_COUNT
) -> tuple[Path, dict[str, Any], dict[str, Any]]:
    """The object's network from the generic one (`train.network.zeroshot`) with its presence
    threshold measured on `count` renders of it (a quarter per blur level), written to
    run/zero-shot.pt -> (that checkpoint, the generic network's card, what the threshold
    measured and the backgrounds left out)."""
    from train.network.zeroshot import (
        alignment_scores,
        load_generic,
        object_checkpoint,
        object_network,
        presence_threshold,
    )
    from train.synth.generate import backgrounds_for, render_in_memory

    excluded = backgrounds_for(profile, SIZES[2]).excluded
    net, generic_card = load_generic(generic)
    net = object_network(profile, net)
    images, classes = [], []
    for b in BLUR_LEVELS:  # a quarter of the threshold renders at each blur level
        spec = DatasetSpec("free", 2, b, count // 4, THRESHOLD_SEED + b, profile)
        im, k = render_in_memory(spec)
        images.append(im)
        classes.append(k)
    score, p_logit = alignment_scores(net, np.concatenate(images))
    threshold, bias, rates = presence_threshold(score, p_logit, np.concatenate(classes) > 0)
    net.presence_corr.fill_(threshold)
    net.presence_bias.fill_(bias)
    checkpoint = object_checkpoint(net, profile, generic_card, run / "zero-shot.pt")
    info = {
        "generic": repo_path(generic),
        "generic_steps": generic_card.get("steps"),
        "presence_threshold": threshold,
        "presence_logit_bias": bias,
        "threshold_renders": int(len(score)),
        **rates,
        "backgrounds_excluded": list(excluded),
    }
    return checkpoint, generic_card, info


def marked_zero_shot(path: Path, card: dict[str, Any], info: dict[str, Any]) -> dict[str, Any]:
    """An exported zero-shot model's card with `info` (its threshold's figures) as its
    `zero_shot`, written into the graph at `path` and beside it (what the service reads as
    zero-shot: `service.pipeline.model.training_of`) -> that card."""
    card = {**card, "zero_shot": info}
    path.write_bytes(with_card(path.read_bytes(), card))
    path.with_suffix(".json").write_text(json.dumps(card, indent=1) + "\n")
    return card


def zero_shot_model(
    profile: Profile,
    run: Path,
    models: Path,
    generic: Path,
    say: Callable[[str], None] = print,
    eval_count: int = ZERO_SHOT_EVAL_COUNT,
    threshold_count: int = THRESHOLD_COUNT,
) -> tuple[Path, dict[str, Any]]:
    """The object's model from the generic network, no training (`zero_shot_checkpoint`),
    exported to `models` with a card that says it is zero-shot and what it measured on other
    renders (`eval_count` per blur level; its threshold on `threshold_count`) -> (ONNX path,
    card)."""
    checkpoint, generic_card, info = zero_shot_checkpoint(profile, run, generic, threshold_count)
    evals = [run / "data" / f"zero-shot-b{b}" for b in BLUR_LEVELS]
    jobs = [
        (DatasetSpec("free", 2, b, eval_count, ZERO_SHOT_EVAL_SEED + b, profile), path)
        for b, path in zip(BLUR_LEVELS, evals, strict=True)
    ]
    make_datasets([(s, p) for s, p in jobs if not (p / MANIFEST_FILE).is_file()], overwrite=True)
    notes = (
        f"Zero-shot: the generic corner network (corners-any, {generic_card.get('steps')} "
        f"training steps on renders of other textures) with the picture of {profile.name}; "
        "not trained on this object. `planar-pose object train` fine-tunes it."
    )
    path, card = export(checkpoint, model_name(profile), models, evals, "all", "0.1.0", notes)
    card = marked_zero_shot(path, card, info)
    say(
        f"presence threshold {info['presence_threshold']:.2f} on {info['threshold_renders']} "
        f"renders: present right {100 * info['present_right']:.1f} %, "
        f"absent right {100 * info['absent_right']:.1f} %"
    )
    return path, card
