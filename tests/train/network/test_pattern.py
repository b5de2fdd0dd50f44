"""train/network/pattern.py: the checker measured from the texture, cells and template order."""

from __future__ import annotations

import numpy as np
import pytest

from service.core.profile import load_profile
from train.network.pattern import Pattern, pattern_from_texture, pattern_of


def test_the_chessboard_texture_is_measured_as_the_checker() -> None:
    chess = load_profile("chessboard")
    pattern = pattern_from_texture(chess.texture_rgb(), chess.width_cm, chess.height_cm)
    assert pattern.checker and pattern.cells == (10, 7)
    # the colours inverted are another texture: corner 0 would be white
    inverted = pattern_from_texture(255 - chess.texture_rgb(), chess.width_cm, chess.height_cm)
    assert not inverted.checker
    charuco = pattern_of(load_profile("charuco").manifest_entry())
    assert charuco is not None and not charuco.checker and charuco.cells == (8, 10)
    assert pattern_of(None) is None and pattern_of({"name": "x"}) is None


def test_templates_are_read_in_the_object_frame() -> None:
    """(s, t) = (0, 0) is corner 0 (-X, -Y): the texture's bottom-left, row 0 its top."""
    grey = np.zeros((40, 60), np.float32)
    grey[20:, :30] = 1.0  # bright bottom-left quarter
    pattern = Pattern(grey, (6, 4), False)
    values = pattern.sample(np.array([[0.25, 0.25], [0.75, 0.25], [0.75, 0.75], [0.25, 0.75]]))
    assert values[0] > 0 and np.all(values[1:] < 0)
    assert values.mean() == pytest.approx(0.0, abs=1e-9)
    assert np.sqrt((values**2).mean()) == pytest.approx(1.0)
    assert pattern.cell_centres().shape == (24, 2)
