"""`planar-pose data ...`: sets, grid, contact sheet, roll; clear errors and exit codes."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import pytest
from typer.testing import CliRunner

from service.core.paths import ASSETS_DIR
from service.core.profile import PROFILES_DIR
from train.cli import app

runner = CliRunner()
REAL = ASSETS_DIR / "real" / "chessboard-stereo"


def _run(*args: str):
    result = runner.invoke(app, ["data", *args])
    return result, result.output  # stdout and stderr


@pytest.fixture(scope="module")
def made(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("cli") / "set"
    result, text = _run(
        "make",
        str(out),
        "--variant",
        "C",
        "--size",
        "1",
        "--blur",
        "1",
        "--count",
        "27",
        "--seed",
        "4",
        "--workers",
        "1",
    )
    assert result.exit_code == 0, text
    assert "27 images" in text
    return out


def test_make_writes_a_set(made):
    manifest = json.loads((made / "manifest.json").read_text())
    assert (manifest["variant"], manifest["blur"], manifest["count"]) == ("C", 1, 27)
    assert manifest["jitter"] is True
    assert len(list((made / "images").glob("*.png"))) == 27


def test_sheet(made, tmp_path):
    out = tmp_path / "sheets" / "s.png"
    result, text = _run("sheet", str(made), str(out), "--per-class", "3")
    assert result.exit_code == 0, text
    image = cv2.imread(str(out))
    assert image is not None and image.shape[0] > 9 * 120 and image.shape[1] > 3 * 160
    result, text = _run("sheet", str(made), str(tmp_path / "s.jpg"))
    assert result.exit_code == 2 and ".png" in text
    result, text = _run("sheet", str(tmp_path / "none"), str(out))
    assert result.exit_code == 1 and "not found" in text


def test_grid_names_and_no_jitter(tmp_path):
    result, text = _run("grid", str(tmp_path), "--count", "9", "--no-jitter", "--workers", "1")
    assert result.exit_code == 0, text
    names = sorted(p.name for p in tmp_path.iterdir())
    expected = sorted(f"{v}-s{s}-b{b}" for v in ("C", "noC") for s in (1, 2) for b in range(4))
    assert names == expected
    manifest = json.loads((tmp_path / "noC-s2-b3" / "manifest.json").read_text())
    assert manifest["size"] == [160, 120] and manifest["blur"] == 3
    assert manifest["jitter"] is False


def test_roll(tmp_path):
    result, text = _run("roll", str(REAL / "labels.csv"))
    assert result.exit_code == 0 and "26 photos" in text and "max 175.4" in text
    result, text = _run("roll", str(tmp_path / "none.csv"))
    assert result.exit_code == 2 and "not found" in text


@pytest.mark.parametrize(
    "args,code,message",
    [
        (["--count", "5"], 2, "count must be at least 9"),
        (["--variant", "D"], 2, "variant must be one of C, noC, free"),
        (["--size", "3"], 2, "size must be 1"),
        (["--blur", "7"], 2, "blur must be 0, 1, 2 or 3"),
        (["--profile", "unknown-object"], 1, "unknown profile"),
        (["--count", "many"], 2, "--count"),
    ],
)
def test_bad_arguments(tmp_path, args, code, message):
    result, text = _run("make", str(tmp_path / "o"), *args)
    assert result.exit_code == code and message in text, text
    assert "Traceback" not in text
    assert not (tmp_path / "o" / "labels.csv").exists()


def test_unreadable_texture_and_existing_folder(tmp_path, made):
    folder = tmp_path / "prof"
    shutil.copytree(PROFILES_DIR / "chessboard", folder)
    (folder / "texture.png").write_bytes(b"broken")
    result, text = _run("make", str(tmp_path / "o"), "--profile", str(folder))
    assert result.exit_code == 1 and "cannot read texture" in text
    result, text = _run("make", str(made), "--count", "9")
    assert result.exit_code == 2 and "not empty" in text and "--overwrite" in text
