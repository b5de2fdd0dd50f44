"""Where the repository's files are: its root and the training side's data files."""

from __future__ import annotations

from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[2]
#: The training side's data files: profiles/, backgrounds/, real/ (absent in the service image).
ASSETS_DIR = REPO_ROOT / "train" / "assets"


def repo_relative(path: Path) -> str:
    """`path` relative to the repository root (POSIX) when inside it, else absolute."""
    try:
        return path.resolve().relative_to(REPO_ROOT).as_posix()
    except ValueError:
        return str(path.resolve())
