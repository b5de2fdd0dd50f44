"""A user's own object end to end, at a test-sized budget: `object new` from a picture (no
zero-shot model: tests/train/test_object_path.py serves that), `object train` (renders, the
corner network fine-tuned, export with its card), then the service answers it beside the
default model (`?model=NAME`)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from service.app import create_app
from service.core.paths import DEFAULT_MODEL
from service.settings import Settings
from train.cli import app
from train.network.zeroshot import GENERIC_WEIGHTS

runner = CliRunner()


@pytest.mark.timeout(600)  # renders, training and an ONNX export: a minute on a loaded machine
def test_from_a_picture_to_a_trained_served_model(tmp_path: Path, poster: Path) -> None:
    profiles, models = tmp_path / "profiles", tmp_path / "models"
    args = ["object", "new", "poster", "--texture", str(poster), "--profiles", str(profiles)]
    args += ["--models", str(models), "--no-zero-shot", "--size", "30", "20"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output

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
