"""The generic corner network measured on objects no network saw (`scripts/any_eval.py`).

For each object (the held-back test textures, `train.synth.textures.held_out_textures`, each
written as a profile of the book's camera, lens and border; and shipped profiles such as the
book and the ChArUco board, neither of which is in the texture bank):

    zero-shot   the generic network with the object's picture, its presence threshold measured
                on renders of it (`train.network.pipeline.zero_shot_checkpoint`)
    test sets   independent renders: other seeds (cameras, backgrounds) than the threshold's,
                one set per SPEC blur level, 160 x 120, classes 0-8 balanced
    answers     the zero-shot model file (exported as `object new` writes it) and the object's
                shipped model where it has one (`models/`), each through the service's path
                (`service.pipeline.Predictor`, nothing known of the camera), with the anatomy
                of their answers (`train.compare.answers`); and the feature-matching peer
                (SIFT, RANSAC, PnP: `train.compare.baseline`, no tuning)
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from service.core.blur import BLUR_LEVELS
from service.core.dataset import MANIFEST_FILE, load_dataset
from service.core.paths import REPO_ROOT
from service.core.profile import PROFILES_DIR, Profile, load_profile, write_profile
from service.pipeline import PoseModel, Predictor, Settings
from train.compare.answers import answer_all, dataset_photos
from train.compare.baseline import BaselineConfig
from train.compare.peers import run_baseline_on
from train.network.export import export
from train.network.pipeline import marked_zero_shot, model_name, zero_shot_checkpoint
from train.synth.generate import DatasetSpec, make_datasets
from train.synth.textures import held_out_textures

#: Seed of the test sets (blur level b: + b), apart from every seed the threshold uses.
TEST_SEED = 8100


def test_profiles(root: Path) -> list[Profile]:
    """The held-back test textures as profiles under root/NAME (the book's profile file with
    the texture's size; written once)."""
    book = (load_profile("book").path).read_text(encoding="utf-8")
    out = []
    for texture in held_out_textures():
        name = "test-" + texture.source.split(":")[-1].replace("/", "-").replace(".jpg", "")
        folder = root / name
        if not (folder / "profile.toml").is_file():
            write_profile(folder, name, texture.rgb, texture.width_cm, texture.height_cm)
            text = book.replace('name = "book"', f'name = "{name}"')
            text = text.replace("width_cm = 15", f"width_cm = {texture.width_cm:.3f}")
            text = text.replace("height_cm = 21", f"height_cm = {texture.height_cm:.3f}")
            (folder / "profile.toml").write_text(text, encoding="utf-8")
        out.append(load_profile(folder))
    return out


def test_sets(profile: Profile, run: Path, count: int) -> list[Path]:
    """The object's test sets, one per blur level (module doc), rendered once into run/."""
    sets = [run / "data" / f"test-b{b}" for b in BLUR_LEVELS]
    jobs = [
        (DatasetSpec("free", 2, b, count, TEST_SEED + b, profile), path)
        for b, path in zip(BLUR_LEVELS, sets, strict=True)
    ]
    todo = [(s, p) for s, p in jobs if not (p / MANIFEST_FILE).is_file()]
    if todo:
        make_datasets(todo, overwrite=True)
    return sets


def _service_answers(model: Path, sets: list[Path]) -> list[dict[str, float | None]]:
    """The anatomy of a model file's answers through the service's path, per set
    (`train.compare.answers`; the refinement's budget at its largest, so that the answers do
    not depend on the machine's load)."""
    predictor = Predictor(PoseModel.load(model), Settings(refine_budget_ms=10_000))
    rows = []
    for path in sets:
        photos = dataset_photos(path)
        rows.append(answer_all(predictor, photos, [None] * len(photos)).as_dict())
    return rows


def _peer_accuracy(path: Path, profile: Profile) -> dict[str, Any]:
    """The feature-matching peer's accuracy and class-0 accuracy on one set; a texture with
    too few features to match gets what the peer then answers: no object, on every image."""
    try:
        m, _ = run_baseline_on(
            path, BaselineConfig(features="sift"), "all", False, str(profile.path)
        )
    except ValueError as exc:  # the peer cannot match this texture (train.real.corners)
        labels = load_dataset(path).labels
        return {"accuracy": float((labels == 0).mean()), "class0": 1.0, "note": str(exc)}
    return {"accuracy": m["accuracy"], "class0": m["per_class_accuracy"][0]}


def evaluate_object(
    profile: Profile,
    generic: Path,
    run: Path,
    count: int,
    peer: bool = True,
    fine_tuned: Path | None = None,
) -> dict[str, Any]:
    """The object's figures (module doc): per blur level the zero-shot model's answers, the
    shipped model's, a `fine_tuned` model file's (`object train` from the generic network)
    and the peer's where measured; the threshold's."""
    checkpoint, _, info = zero_shot_checkpoint(profile, run, generic)
    sets = test_sets(profile, run, count)
    model, card = export(checkpoint, model_name(profile), run / "model")
    marked_zero_shot(model, card, info)  # served as `object new` serves it
    row: dict[str, Any] = {"object": profile.name, "threshold": info, "count": count}
    row["zero_shot"] = _service_answers(model, sets)
    shipped = REPO_ROOT / "models" / f"{model_name(profile)}.onnx"
    if shipped.is_file() and profile.path.parent.parent == PROFILES_DIR:  # a shipped object
        row["shipped"] = _service_answers(shipped, sets)
    if fine_tuned is not None:
        row["fine_tuned"] = _service_answers(fine_tuned, sets)
    if peer:
        row["peer"] = [_peer_accuracy(path, profile) for path in sets]
    return row


def mean_of(rows: list[dict[str, Any]], key: str, blur: int) -> float:
    """The mean over objects of `key`'s accuracy at a blur level (nan where none has it)."""
    values = [r[key][blur]["accuracy"] for r in rows if key in r]
    return float(np.mean(values)) if values else float("nan")
