"""Where the repository's files are: its root, the shipped models (and the default one) and
the training side's data files."""

from __future__ import annotations

from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[2]
#: The training side's data files: profiles/, backgrounds/, real/ (absent in the service image).
ASSETS_DIR = REPO_ROOT / "train" / "assets"
#: The shipped models (`models/<name>.onnx` with its card).
DEFAULT_MODEL_DIR = REPO_ROOT / "models"
#: The shipped model that /v1/predict answers with: object, network, input size.
DEFAULT_MODEL_NAME = "chessboard-corners-160x120"
DEFAULT_MODEL = DEFAULT_MODEL_DIR / f"{DEFAULT_MODEL_NAME}.onnx"


def repo_relative(path: Path) -> str:
    """`path` relative to the repository root (POSIX) when inside it, else absolute."""
    try:
        return path.resolve().relative_to(REPO_ROOT).as_posix()
    except ValueError:
        return str(path.resolve())
