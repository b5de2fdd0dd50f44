"""Fixtures shared by the training-side tests."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from service.core.profile import load_profile
from train.synth.generate import DatasetSpec, make_dataset


@pytest.fixture(scope="session")
def tiny_set(tmp_path_factory) -> Path:
    """A tiny synthetic noC 80x60 data set (180 images, 60/20/20) made by the generator."""
    out = tmp_path_factory.mktemp("data") / "tiny"
    make_dataset(out, DatasetSpec("noC", 1, 0, 180, 3, load_profile("chessboard")))
    return out


@pytest.fixture
def poster(tmp_path: Path) -> Path:
    """A textured poster's picture, 300x200 px (`object new`'s input): smooth noise with a
    few shapes and a word (features everywhere) -> its path."""
    path = tmp_path / "poster.jpg"
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
