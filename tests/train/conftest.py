"""Fixtures shared by the training-side tests."""

from __future__ import annotations

from pathlib import Path

import pytest

from service.core.profile import load_profile
from train.synth.generate import DatasetSpec, make_dataset


@pytest.fixture(scope="session")
def tiny_set(tmp_path_factory) -> Path:
    """A tiny synthetic noC 80x60 data set (180 images, 60/20/20) made by the generator."""
    out = tmp_path_factory.mktemp("data") / "tiny"
    make_dataset(out, DatasetSpec("noC", 1, 0, 180, 3, load_profile("chessboard")))
    return out
