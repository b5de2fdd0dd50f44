"""A user's own object end to end, at a test-sized budget: `object new` from a picture,
`object train` (renders, corner network, export with its card), then the service answers it
beside the default model (`?model=NAME`)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from service.app import create_app
from service.core.paths import DEFAULT_MODEL
from service.core.profile import load_profile
from service.pipeline.model import PoseModel
from service.settings import Settings
from train.cli import app
from train.network.zeroshot import GENERIC_WEIGHTS

runner = CliRunner()


def _picture(path: Path) -> Path:
    """A textured poster, 300x200 px: smooth noise with a few shapes (features everywhere)."""
    rng = np.random.default_rng(5)
    noise = cv2.resize(rng.random((8, 12)).astype(np.float32), (300, 200), cv2.INTER_CUBIC)
    rgb = (np.stack([noise, noise[::-1], noise[:, ::-1]], -1) * 200 + 30).clip(0, 255)
    rgb = np.ascontiguousarray(rgb.astype(np.uint8))
    for _ in range(12):
        centre = (int(rng.integers(20, 280)), int(rng.integers(20, 180)))
        colour = tuple(int(c) for c in rng.integers(0, 255, 3))
        cv2.circle(rgb, centre, int(rng.integers(6, 25)), colour, -1)
    cv2.putText(rgb, "POSE", (60, 130), cv2.FONT_HERSHEY_SIMPLEX, 2.2, (10, 10, 10), 6)
    cv2.imwrite(str(path), rgb)
    return path


@pytest.mark.timeout(900)  # zero-shot, fine-tuning and serving: minutes on a loaded machine
def test_from_a_picture_to_a_served_model(tmp_path: Path) -> None:
    picture = _picture(tmp_path / "poster.jpg")
    profiles, models = tmp_path / "profiles", tmp_path / "models"
    args = ["object", "new", "poster", "--texture", str(picture), "--profiles", str(profiles)]
    args += ["--models", str(models), "--run", str(tmp_path / "run"), "--eval-count", "9"]
    args += ["--threshold-count", "72"]
    result = runner.invoke(app, [*args, "--size", "30", "20"])
    assert result.exit_code == 0, result.output
    assert (profiles / "poster" / "profile.toml").is_file()
    assert cv2.imread(str(profiles / "poster" / "samples.jpg")) is not None
    if GENERIC_WEIGHTS.is_file():  # served at once: the generic network with its picture
        zero_shot = json.loads((models / "poster-corners-160x120.json").read_text())
        assert zero_shot["zero_shot"]["threshold_renders"] > 0, result.output
        assert set(zero_shot["accuracy"]) == {f"zero-shot-b{b}" for b in range(4)}
        served = PoseModel.load(models / "poster-corners-160x120.onnx")  # the graph's own card
        assert served.training == "zero-shot"
    again = runner.invoke(app, [*args, "--size", "30", "20"])
    assert again.exit_code == 1 and "exists" in again.output

    budget = ["--count", "90", "--eval-count", "45", "--epochs", "1", "--batch-size", "16"]
    run = tmp_path / "run"
    train = ["object", "train", str(profiles / "poster"), "--run", str(run)]
    result = runner.invoke(app, [*train, "--models", str(models), *budget, "--no-bf16"])
    assert result.exit_code == 0, result.output
    said = " ".join(result.output.split())  # rich wraps the lines
    assert "expected: under a minute of training on this machine (1 epochs x" in said, said
    assert "shorter: fewer --epochs or --count (now 90)" in said
    manifest = json.loads((run / "data" / "train-free-s2" / "manifest.json").read_text())
    assert manifest["counts"] == {"train": 90, "val": 0, "test": 0}  # selected on the evals'
    onnx = models / "poster-corners-160x120.onnx"
    card = json.loads(onnx.with_suffix(".json").read_text())
    assert card["profile"]["name"] == "poster" and set(card["accuracy"]) == {
        f"free-s2-b{b}" for b in range(4)
    }
    # run again: every step is done, the model written from these weights is kept
    written = onnx.read_bytes()
    result = runner.invoke(app, [*train, "--models", str(models), *budget, "--no-bf16"])
    assert result.exit_code == 0 and "up to date" in result.output, result.output
    assert "train:" not in result.output and "renders:" not in result.output
    assert onnx.read_bytes() == written

    (models / DEFAULT_MODEL.name).write_bytes(DEFAULT_MODEL.read_bytes())
    (models / DEFAULT_MODEL.with_suffix(".json").name).write_bytes(
        DEFAULT_MODEL.with_suffix(".json").read_bytes()
    )
    photo = (run / "data" / "free-s2-b0" / "images").glob("*.png")
    data = next(iter(sorted(photo))).read_bytes()
    with TestClient(create_app(Settings(model_dir=models))) as client:
        for _ in range(600):  # the models load in the background
            if client.get("/readyz").status_code == 200:
                break
            time.sleep(0.05)
        r = client.post("/v1/predict?model=poster-corners-160x120", files={"image": data})
        unknown = client.post("/v1/predict?model=nope", files={"image": data})
        listing = client.get("/v1/models").json()
    assert r.status_code == 200, r.text
    assert r.json()["model"] == "poster-corners-160x120"
    assert unknown.status_code == 404 and "poster-corners-160x120" in unknown.text
    training = {m["name"]: m["training"] for m in listing["models"]}
    assert training[DEFAULT_MODEL.stem] == "trained"
    assert training["poster-corners-160x120"] == (
        "fine-tuned" if GENERIC_WEIGHTS.is_file() else "trained"
    )


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["Bad Name", "--size", "30", "20"], "use lower-case letters"),
        (["poster", "--size", "30", "10"], "aspect"),
        (["poster", "--size", "30", "-20"], "size must be positive"),
    ],
)
def test_object_new_refuses_bad_input(tmp_path: Path, args: list[str], message: str) -> None:
    picture = _picture(tmp_path / "poster.jpg")
    result = runner.invoke(
        app,
        ["object", "new", *args, "--texture", str(picture), "--profiles", str(tmp_path / "p")],
    )
    assert result.exit_code in (1, 2) and message in result.output, result.output


def test_an_export_is_up_to_date_only_for_the_files_it_wrote(tmp_path: Path) -> None:
    """The run's record of its export matches while the checkpoint and the model are the
    ones it wrote; a changed model (or checkpoint) is exported again."""
    from train.network.pipeline import EXPORTED, _digest, _exported

    best, onnx = tmp_path / "best.pt", tmp_path / "models" / "m.onnx"
    onnx.parent.mkdir()
    best.write_bytes(b"weights")
    onnx.write_bytes(b"graph")
    onnx.with_suffix(".json").write_text('{"name": "m"}')
    assert _exported(tmp_path, best, onnx) is None  # no record yet
    marker = {"checkpoint": _digest(best), "onnx": str(onnx.resolve()), "model": _digest(onnx)}
    (tmp_path / EXPORTED).write_text(json.dumps(marker))
    assert _exported(tmp_path, best, onnx) == (onnx, {"name": "m"})
    onnx.write_bytes(b"another graph")
    assert _exported(tmp_path, best, onnx) is None
    onnx.write_bytes(b"graph")
    best.write_bytes(b"trained on")
    assert _exported(tmp_path, best, onnx) is None


def test_object_train_from_scratch_keeps_the_shipped_models_recipe(tmp_path, monkeypatch):
    """`--scratch` renders and selects as the shipped models were made (60 / 20 / 20 splits,
    the epochs selected on the training renders' val split); only the fine-tuning from the
    generic network trains on every render (the object-path test above)."""
    from train.network import pipeline

    seen: dict[str, object] = {}
    monkeypatch.setattr(pipeline, "make_datasets", lambda jobs, **_: seen.update(jobs=jobs))
    monkeypatch.setattr(pipeline, "expected_duration", lambda *_: "")

    def stage(config: pipeline.FitConfig, say: object) -> Path:
        seen["config"] = config
        raise RuntimeError("stop before training")

    monkeypatch.setattr(pipeline, "_stage", stage)
    with pytest.raises(RuntimeError, match="stop before training"):
        pipeline.train_object(
            load_profile("book"), tmp_path, tmp_path / "models", pipeline.ObjectRecipe()
        )
    spec, _ = seen["jobs"][0]  # type: ignore[index]
    assert spec.count == 20000 and not spec.all_train
    assert seen["config"].select == []  # type: ignore[attr-defined]
