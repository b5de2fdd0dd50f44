"""Finer regions: the grid's text, cells and shares (`service.core.cells`)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from service.core.cells import RegionGrid


def test_a_grid_reads_its_text_and_writes_it_back() -> None:
    assert RegionGrid.parse("8x3") == RegionGrid(8, 3)
    grid = RegionGrid.parse(" 12x4x40,80 ")
    assert grid == RegionGrid(12, 4, (40.0, 80.0)) and str(grid) == "12x4x40,80"
    assert grid.size == 12 * 4 * 3


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("8", "expected AxE"),
        ("8x3x", "expected AxE"),
        ("0x3", "1 to 72"),
        ("8x30", "1 to 72"),
        ("8x3x60,40", "increasing"),
        ("8x3x60,60", "increasing"),
        ("8x3x-5", "expected AxE"),
        ("8x3x1e400", "increasing"),
        ("8x3x1.2.3", "must be numbers"),
        ("８x３", "in ASCII digits"),  # full-width digits, which int() would read as 8x3
        ("8x3x６0", "in ASCII digits"),
        ("٨x3", "in ASCII digits"),
        ("8x3\n", "in ASCII digits"),
    ],
)
def test_a_bad_grid_says_what_is_wrong(text: str, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        RegionGrid.parse(text)


def test_a_centre_falls_in_the_cell_whose_ranges_hold_it() -> None:
    grid = RegionGrid(8, 3, (60.0,))
    centres = np.array([[50.0, 0.0, 10.0], [0.0, 30.0, 80.0], [-40.0, -40.0, 30.0]])
    for c, index in zip(centres, grid.indices(centres), strict=True):
        cell = grid.cell(int(index))
        distance = np.linalg.norm(c)
        azimuth = math.degrees(math.atan2(c[1], c[0]))
        elevation = math.degrees(math.asin(c[2] / distance))
        lo, hi = cell.azimuth_deg
        assert lo <= azimuth < hi or lo <= azimuth - 360 < hi or lo <= azimuth + 360 < hi
        assert cell.elevation_deg[0] <= elevation < cell.elevation_deg[1]
        assert cell.distance_cm[0] <= distance < cell.distance_cm[1]
    assert grid.cell(0).azimuth_deg == (-22.5, 22.5) and grid.cell(0).distance_cm == (0.0, 60.0)
    assert grid.cell(grid.size - 1).distance_cm == (60.0, math.inf)
    assert grid.cell(1).label == "az -22.5..22.5, el 0..30, d 60..inf"


def test_sector_zero_wraps_around_the_x_axis() -> None:
    grid = RegionGrid(4, 1)
    below, above = grid.indices(np.array([[10.0, -1.0, 5.0], [10.0, 1.0, 5.0]]))
    assert below == above == 0
    assert grid.indices(np.array([[-10.0, -0.1, 5.0]]))[0] == 2


def test_shares_count_the_samples_largest_first() -> None:
    grid = RegionGrid(4, 1)
    samples = np.array([[10, 0, 5]] * 3 + [[0, 10, 5]])
    assert grid.shares(samples) == {0: 0.75, 1: 0.25}


def test_a_cell_outside_the_grid_is_refused() -> None:
    with pytest.raises(ValueError, match="outside"):
        RegionGrid(2, 2).cell(4)
