"""Labelled images answered through the service's path, with the anatomy of the answers
(train/compare/answers.py)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from service.core.profile import load_profile
from service.pipeline import PoseModel, Predictor, Settings
from train.compare.answers import answer_all, dataset_photos
from train.synth.generate import DatasetSpec, make_dataset


@pytest.fixture(scope="module")
def renders(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """18 renders of the chessboard at 160x120, blur 0, classes 0-8 twice."""
    out = tmp_path_factory.mktemp("answers") / "set"
    make_dataset(out, DatasetSpec("free", 2, 0, 18, 11, load_profile("chessboard")))
    return out


def test_the_anatomy_counts_what_the_service_answers(
    renders: Path, default_model: PoseModel
) -> None:
    photos = dataset_photos(renders)
    n, absent = len(photos), sum(p.label == 0 for p in photos)
    assert (n, absent) == (18, 2)
    assert all((p.corners is None) == (p.label == 0) for p in photos)
    predictor = Predictor(default_model, Settings())
    a = answer_all(predictor, photos, [None] * n)
    assert (a.images, a.absent, a.present) == (n, absent, n - absent)
    assert 0 < a.found <= a.present and a.depth_right <= a.found and a.side_right <= a.found
    shares = a.as_dict()
    assert shares["accuracy"] == a.right / n and shares["class0"] == a.absent_right / absent
    assert shares["corner_px"] is not None and shares["corner_px"] < 3.0  # the default model
    # every label "absent": nothing counts as found, and right is what was answered absent
    none = answer_all(predictor, [replace(p, label=0, corners=None) for p in photos], [None] * n)
    assert none.found == 0 and none.present == 0 and none.corner_px == []
    assert none.right == none.absent_right == n - a.found - (a.absent - a.absent_right)
