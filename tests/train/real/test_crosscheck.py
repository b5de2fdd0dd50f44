"""The independent label check on the stored photos or on full-resolution originals."""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from service.core.paths import ASSETS_DIR
from service.core.profile import load_profile
from train.cli import app
from train.real.calibration import Camera
from train.real.corpus import stored_size
from train.real.crosscheck import crosscheck_folder
from train.real.label import chessboard_pattern

SOURCE = ASSETS_DIR / "real" / "corpus" / "boards" / "opencv__opencv__left"
PHOTOS = 3
runner = CliRunner()


@pytest.fixture
def small_corpus(tmp_path) -> tuple[Path, Path]:
    """A corpus of one board source (3 stored photos of the repository's corpus) and a folder
    of originals for 2 of them: the stored photos upscaled 2x (the third has none)."""
    with (SOURCE / "labels.csv").open(newline="") as fh:
        reader = csv.DictReader(fh)
        fields, rows = reader.fieldnames, list(reader)[:PHOTOS]
    src = tmp_path / "corpus" / "boards" / SOURCE.name
    (src / "images").mkdir(parents=True)
    for row in rows:
        shutil.copy2(SOURCE / row["file"], src / row["file"])
    with (src / "labels.csv").open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=fields)
        writer.writeheader()
        writer.writerows(rows)
    originals = tmp_path / "originals"
    (originals / SOURCE.name / "images").mkdir(parents=True)
    for row in rows[:2]:
        image = cv2.imread(str(SOURCE / row["file"]))
        big = cv2.resize(image, None, fx=2, fy=2, interpolation=cv2.INTER_CUBIC)
        cv2.imwrite(str(originals / SOURCE.name / "images" / row["original"]), big)
    return tmp_path / "corpus", originals


def _check(folder: Path, originals: Path | None = None) -> list[dict]:
    profile = load_profile("chessboard")
    pattern = chessboard_pattern(profile)
    return crosscheck_folder(folder, pattern, float(profile.geometry.z_split_cm), originals)


def test_intrinsics_scaled_back_invert_the_corpus_downscaling():
    K = np.array([[1650.0, 0, 958.3], [0, 1648.0, 541.7], [0, 0, 1]])
    full, small = (1920, 1080), stored_size((1920, 1080))
    assert small == (640, 360) and stored_size((1544, 1032)) == (640, 428)
    assert stored_size((640, 480)) == (640, 480)
    stored = Camera(K, np.zeros(5), full).scaled(small).K  # as the corpus stored the label
    back = Camera(stored, np.zeros(5), small).scaled(full).K
    assert back == pytest.approx(K, abs=1e-9)
    # Pixel centres at integers: pixel 0 of the small image covers pixels 0 and 1 (centre 0.5).
    centre = Camera(np.diag([1.0, 1.0, 1.0]), np.zeros(5), (2, 2)).scaled((4, 4)).K
    assert centre[0, 2] == pytest.approx(0.5) and centre[0, 0] == 2.0


def test_originals_upscaled_2x_give_the_same_class_and_centre(small_corpus):
    corpus, originals = small_corpus
    folder = corpus / "boards" / SOURCE.name
    stored = _check(folder)
    full = _check(folder, originals)
    assert [r["read"] for r in stored] == ["stored"] * PHOTOS
    assert [r["read"] for r in full] == ["original", "original", "stored"]
    assert [r["fallback"] for r in full] == [None, None, "original not found"]
    for s, f in zip(stored, full, strict=True):
        assert f["independent_class"] == s["independent_class"] == f["class"]
        assert f["centre_diff_cm"] < 0.5 and abs(f["centre_diff_cm"] - s["centre_diff_cm"]) < 0.3


def test_an_original_of_another_size_is_not_used(small_corpus):
    corpus, originals = small_corpus
    first = next((originals / SOURCE.name / "images").iterdir())
    cv2.imwrite(str(first), np.zeros((500, 640, 3), np.uint8))  # not 640 x 480 scaled up
    rows = _check(corpus / "boards" / SOURCE.name, originals)
    bad = next(r for r in rows if Path(r["file"]).stem == first.stem)
    assert bad["read"] == "stored" and "another size" in bad["fallback"]
    assert bad["independent_class"] == bad["class"]


def test_cli_says_which_photos_it_read(small_corpus):
    corpus, originals = small_corpus
    result = runner.invoke(app, ["corpus", "check", "--corpus", str(corpus)])
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    assert "3 / 3 agree" in text and "Photos read: the 3 stored photos" in text
    args = ["corpus", "check", "--corpus", str(corpus), "--originals", str(originals)]
    result = runner.invoke(app, [*args, "--disagreements"])
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    assert "3 / 3 agree (read 2 originals, 1 stored)" in text
    assert "full-resolution originals (which the labels were made from) of 2 photos" in text
    assert "of the other 1 (original not found: 1" in text
    assert "not in the repository" in text


def test_cli_bad_originals_folder_is_a_clean_error(small_corpus, tmp_path):
    corpus, _ = small_corpus
    missing = tmp_path / "nowhere"
    for cmd in ("check", "report"):
        result = runner.invoke(
            app, ["corpus", cmd, "--corpus", str(corpus), "--originals", str(missing)]
        )
        assert result.exit_code == 1 and "--originals folder not found" in result.output
        assert result.exception is None or isinstance(result.exception, SystemExit)
    a_file = tmp_path / "file.txt"
    a_file.write_text("x")
    result = runner.invoke(
        app, ["corpus", "check", "--corpus", str(corpus), "--originals", str(a_file)]
    )
    assert result.exit_code == 1 and "--originals is not a folder" in result.output
    assert "Traceback" not in result.output
