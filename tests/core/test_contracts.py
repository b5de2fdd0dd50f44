"""The contracts of `service.core` pinned: what exported graphs, data sets and answers rely on.

Changing one of these values breaks every shipped model, data set or client that uses it; a
change here must be deliberate (a new model version, a data-set format version).
"""

from __future__ import annotations

import itertools

import numpy as np
import onnxruntime as ort
import pytest

from service.core import onnx_contract as contract
from service.core.dataset import CORNER_COLUMNS, LABEL_COLUMNS, SPLITS
from service.core.frame import CORNER_ORDER, object_corners
from service.core.inputs import SIZES, focal_scale, size_index, spec_fx
from service.core.regions import (
    NUM_CLASSES,
    boundary_margin_cm,
    is_far,
    pose_class,
    quadrant_of_class,
    region_of_class,
)
from service.settings import Settings


def test_corner_order_is_bottom_left_then_counter_clockwise() -> None:
    assert CORNER_ORDER == "(-X,-Y), (+X,-Y), (+X,+Y), (-X,+Y)"
    corners = object_corners(25.0, 17.5)
    np.testing.assert_array_equal(
        corners, [[-12.5, -8.75], [12.5, -8.75], [12.5, 8.75], [-12.5, 8.75]]
    )
    np.testing.assert_array_equal(object_corners(25.0, 17.5, z=True)[:, :2], corners)
    assert not object_corners(4.0, 2.0, z=True)[:, 2].any()


def test_data_set_columns_and_splits() -> None:
    assert SPLITS == ("train", "val", "test")
    assert [f"corner_{a}{i}" for i in range(4) for a in "xy"] == CORNER_COLUMNS
    assert LABEL_COLUMNS[:2] == ["file", "class"]
    assert LABEL_COLUMNS[-8:] == CORNER_COLUMNS
    for name in ("cam_x", "cam_y", "cam_z", "blur", "split", "roll_deg", "focal_scale", "k1"):
        assert name in LABEL_COLUMNS


def test_input_sizes() -> None:
    assert SIZES == {1: (80, 60), 2: (160, 120)}
    assert size_index((160, 120)) == 2 and size_index(1) == 1
    with pytest.raises(ValueError, match="80x60"):
        size_index((100, 100))
    assert focal_scale(spec_fx(640), 640) == pytest.approx(1.0)


@pytest.mark.parametrize("sx, sy, far", list(itertools.product((1, -1), (1, -1), (False, True))))
def test_region_rule_agrees_with_its_words(sx: int, sy: int, far: bool) -> None:
    z_split = 60.0
    centre = np.array([sx * 3.0, sy * 4.0, z_split + (5.0 if far else -5.0)])
    k = int(pose_class(centre, z_split))
    region = region_of_class(k)
    assert region["x"] == ("+" if sx > 0 else "-") and region["y"] == ("+" if sy > 0 else "-")
    assert region["depth"] == ("far" if far else "near") and bool(is_far(k)) == far
    assert int(quadrant_of_class(k)) == (k - 1) % 4 + 1
    assert float(boundary_margin_cm(centre, z_split)) == pytest.approx(3.0)


def test_region_rule_borders_belong_to_the_positive_side_and_far() -> None:
    assert int(pose_class([0.0, 0.0, 60.0], 60.0)) == 5
    assert int(pose_class([-1e-9, 0.0, 59.9], 60.0)) == 2
    assert [region_of_class(k)["present"] for k in range(NUM_CLASSES)] == [False] + [True] * 8


def test_the_default_model_has_the_graph_contract() -> None:
    """The shipped default graph: the inputs and outputs `service.pipeline.model` reads, by name."""
    session = ort.InferenceSession(
        str(Settings().resolved_model_path), providers=["CPUExecutionProvider"]
    )
    inputs = {i.name: i.shape for i in session.get_inputs()}
    overridable = {i.name for i in session.get_overridable_initializers()}
    outputs = {o.name: o.shape for o in session.get_outputs()}
    assert inputs[contract.IMAGE][1:] == [3, *SIZES[2][::-1]]
    assert set(inputs) == {contract.IMAGE} and overridable == set(contract.DEFAULTS)
    assert set(outputs) == {
        contract.PROBABILITIES,
        contract.CORNERS,
        contract.PATTERN,
        contract.UNDISTORTED,
    }
    assert outputs[contract.PROBABILITIES][1:] == [NUM_CLASSES]
    assert outputs[contract.CORNERS][1:] == outputs[contract.UNDISTORTED][1:] == [4, 2]
    assert contract.CARD_KEY in session.get_modelmeta().custom_metadata_map


def test_the_card_describes_every_input_and_output() -> None:
    text = contract.io_description(corners=True)
    for name in (*contract.DEFAULTS, *contract.OUTPUTS, contract.IMAGE):
        assert f"{name}:" in text["input_format"] + text["output"]
    assert CORNER_ORDER in text["output"]
    assert contract.CORNERS not in contract.io_description(corners=False)["output"]
