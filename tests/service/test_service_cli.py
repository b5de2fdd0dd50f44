"""service.settings and `planar-pose-serve` (also `planar-pose serve`): environment parsing,
bad settings -> exit 2, no training code imported."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from pydantic import ValidationError
from typer.testing import CliRunner

from service.cli import serve_app as app
from service.core.paths import DEFAULT_MODEL, DEFAULT_MODEL_NAME
from service.settings import Settings


def test_defaults_serve_the_shipped_model(monkeypatch: pytest.MonkeyPatch) -> None:
    for key in list(Settings.model_fields):
        monkeypatch.delenv(f"POSE_{key.upper()}", raising=False)
    settings = Settings()
    assert settings.resolved_model_path == DEFAULT_MODEL and DEFAULT_MODEL.is_file()
    assert (settings.host, settings.port, settings.api_key) == ("127.0.0.1", 8000, None)


def test_environment_lists_and_secrets(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("POSE_CORS_ORIGINS", "https://a.example, https://b.example")
    monkeypatch.setenv("POSE_SLIDING_SCALES", "[1, 0.5]")
    monkeypatch.setenv("POSE_API_KEY", "s3cr3t-value")
    monkeypatch.setenv("POSE_MODEL_PATH", "/x/m.onnx")
    settings = Settings()
    assert settings.cors_origins == ["https://a.example", "https://b.example"]
    assert settings.sliding_scales == [1.0, 0.5]
    assert settings.api_key is not None and settings.api_key.get_secret_value() == "s3cr3t-value"
    assert "s3cr3t" not in repr(settings)
    assert settings.resolved_model_path == Path("/x/m.onnx")
    monkeypatch.setenv("POSE_API_KEY", "")
    assert Settings().api_key is None


@pytest.mark.parametrize(
    ("field", "value"),
    [("port", "0"), ("max_images", "0"), ("sliding_scales", "1,2"), ("sliding_nms_iou", "0")],
)
def test_bad_settings_rejected(field: str, value: str) -> None:
    with pytest.raises(ValidationError):
        Settings(**{field: value})


runner = CliRunner()


def test_serve_missing_model_exits_2(tmp_path: Path) -> None:
    result = runner.invoke(app, ["--model", str(tmp_path / "none.onnx")])
    assert result.exit_code == 2
    assert "model file not found" in result.output


def test_serve_bad_environment_exits_2(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("POSE_MAX_PIXELS", "lots")
    result = runner.invoke(app, [])
    assert result.exit_code == 2 and "max_pixels" in result.output


def test_serve_bad_port_flag_exits_2() -> None:
    assert runner.invoke(app, ["--port", "70000"]).exit_code == 2


def test_uvicorn_entry_with_bad_environment_says_why() -> None:
    env = {**os.environ, "POSE_MAX_IMAGES": "-3"}
    done = subprocess.run(
        [sys.executable, "-m", "uvicorn", "service.app:app", "--port", "1"],
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 1
    assert "invalid settings" in done.stderr and "max_images" in done.stderr
    assert "Traceback" not in done.stderr


def test_the_service_imports_no_training_code() -> None:
    code = (
        "import sys, service.app, service.cli\n"
        "print(sorted(m for m in sys.modules if m == 'train' or m.startswith(('train.', 'torch'))))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


def test_planar_pose_serve_still_works_from_the_training_cli(tmp_path: Path) -> None:
    from train.cli import app as train_app

    result = runner.invoke(train_app, ["serve", "--model", str(tmp_path / "none.onnx")])
    assert result.exit_code == 2 and "model file not found" in result.output


def test_serve_missing_model_folder_and_bad_workers_exit_2(tmp_path: Path) -> None:
    result = runner.invoke(app, ["--model-dir", str(tmp_path / "none")])
    assert result.exit_code == 2 and "model folder not found" in result.output
    assert runner.invoke(app, ["--workers", "-1"]).exit_code == 2


def test_worker_settings_and_model_files(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    from service.pipeline.registry import ModelRegistry

    monkeypatch.setenv("POSE_WORKERS", "3")
    monkeypatch.setenv("POSE_MODEL_DIR", str(tmp_path))
    settings = Settings()
    assert settings.process_count == 3 and settings.resolved_model_dir == tmp_path
    assert settings.resolved_model_path == tmp_path / f"{DEFAULT_MODEL_NAME}.onnx"
    (tmp_path / "a.onnx").write_bytes(b"")
    (tmp_path / "b.json").write_text("{}")
    assert ModelRegistry(settings).files() == {"a": tmp_path / "a.onnx"}
    only = Settings(model_path=tmp_path / "x.onnx", model_dir=None)
    assert ModelRegistry(only).files() == {DEFAULT_MODEL_NAME: tmp_path / "x.onnx"}
    both = Settings(model_path=tmp_path / "x.onnx")  # POSE_MODEL_DIR still set
    assert ModelRegistry(both).files() == {
        "a": tmp_path / "a.onnx",
        DEFAULT_MODEL_NAME: tmp_path / "x.onnx",
    }
