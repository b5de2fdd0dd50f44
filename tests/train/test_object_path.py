"""A user's own object from its picture: `object new` (the profile, the zero-shot model served
at once) and its refusals, and `object train`'s recipe and export records (its whole path:
tests/train/test_object_train.py)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import pytest
from typer.testing import CliRunner

from service.core.profile import load_profile
from service.pipeline.model import PoseModel
from train.cli import app
from train.network.zeroshot import GENERIC_WEIGHTS

runner = CliRunner()


@pytest.mark.timeout(600)  # zero-shot renders and an ONNX export: a minute on a loaded machine
def test_a_new_object_is_served_at_once_by_the_generic_network(
    tmp_path: Path, poster: Path
) -> None:
    """`object new`: the profile, and (where the generic weights are shipped) the zero-shot
    model, its presence threshold and accuracy measured, served with its own card."""
    profiles, models = tmp_path / "profiles", tmp_path / "models"
    args = ["object", "new", "poster", "--texture", str(poster), "--profiles", str(profiles)]
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


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["Bad Name", "--size", "30", "20"], "use lower-case letters"),
        (["poster", "--size", "30", "10"], "aspect"),
        (["poster", "--size", "30", "-20"], "size must be positive"),
    ],
)
def test_object_new_refuses_bad_input(
    tmp_path: Path, poster: Path, args: list[str], message: str
) -> None:
    result = runner.invoke(
        app,
        ["object", "new", *args, "--texture", str(poster), "--profiles", str(tmp_path / "p")],
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
