"""Finer regions: a grid of azimuth sectors x elevation bands x distance bands around the object.

A grid is written `AxE` or `AxExD1,D2,...` (e.g. `8x3`, `12x4x40,80`): A azimuth sectors of
equal angle, sector 0 centred on azimuth 0 (the object's +x side) and counting towards +y;
E elevation bands of equal angle over 0..90 degrees (band 0 grazing); distance bands split
at D1 < D2 < ... cm (none: one band). Azimuth, elevation and distance are the camera
centre's in the object frame (`service.core.pose.CameraPose`). A cell's index is
(sector * E + band) * bands_of_distance + distance band.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

MAX_SECTORS, MAX_BANDS, MAX_SPLITS = 72, 18, 16
#: ASCII digits only (`\d` would read full-width and other Unicode digits), the whole text.
_GRID = re.compile(r"([0-9]{1,3})x([0-9]{1,3})(?:x([0-9.,eE+]+))?", re.ASCII)


@dataclass(frozen=True)
class Cell:
    """One cell of a grid: its index and its azimuth, elevation (degrees) and distance (cm)
    ranges [lo, hi) (hi of the last distance band: inf)."""

    index: int
    azimuth_deg: tuple[float, float]
    elevation_deg: tuple[float, float]
    distance_cm: tuple[float, float]

    @property
    def label(self) -> str:
        def span(lo: float, hi: float) -> str:
            return f"{lo:g}..{hi:g}"

        return (
            f"az {span(*self.azimuth_deg)}, el {span(*self.elevation_deg)}, "
            f"d {span(*self.distance_cm)}"
        )


@dataclass(frozen=True)
class RegionGrid:
    """Azimuth sectors, elevation bands and distance splits (cm); `parse` reads the text."""

    sectors: int
    bands: int
    splits: tuple[float, ...] = ()

    @classmethod
    def parse(cls, text: str) -> RegionGrid:
        """`AxE` or `AxExD1,D2,...` -> the grid; ValueError saying what is wrong."""
        match = _GRID.fullmatch(text.strip(" \t"))
        if match is None:
            raise ValueError(
                f"regions: expected AxE or AxExD1,D2,... in ASCII digits (e.g. 8x3 or 8x3x60), "
                f"got {text!r}"
            )
        sectors, bands = int(match[1]), int(match[2])
        if not (1 <= sectors <= MAX_SECTORS and 1 <= bands <= MAX_BANDS):
            raise ValueError(
                f"regions: 1 to {MAX_SECTORS} azimuth sectors and 1 to {MAX_BANDS} elevation "
                f"bands, got {sectors}x{bands}"
            )
        splits: tuple[float, ...] = ()
        if match[3]:
            try:
                splits = tuple(float(d) for d in match[3].split(","))
            except ValueError:
                raise ValueError(
                    f"regions: distance splits must be numbers, got {match[3]!r}"
                ) from None
            ok = all(math.isfinite(d) and d > 0 for d in splits)
            if not ok or list(splits) != sorted(set(splits)) or len(splits) > MAX_SPLITS:
                raise ValueError(
                    f"regions: up to {MAX_SPLITS} increasing positive distance splits (cm), "
                    f"got {match[3]!r}"
                )
        return cls(sectors, bands, splits)

    def __str__(self) -> str:
        tail = "x" + ",".join(f"{d:g}" for d in self.splits) if self.splits else ""
        return f"{self.sectors}x{self.bands}{tail}"

    @property
    def size(self) -> int:
        return self.sectors * self.bands * (len(self.splits) + 1)

    def indices(self, centres: np.ndarray) -> np.ndarray:
        """Camera centres [N, 3] cm in the object frame -> their cells' indices [N]."""
        c = np.asarray(centres, np.float64).reshape(-1, 3)
        distance = np.linalg.norm(c, axis=1)
        azimuth = np.degrees(np.arctan2(c[:, 1], c[:, 0]))
        elevation = np.degrees(np.arcsin(np.clip(c[:, 2] / np.maximum(distance, 1e-9), -1, 1)))
        width = 360.0 / self.sectors
        sector = np.floor((azimuth + width / 2) / width).astype(int) % self.sectors
        band = np.clip(np.floor(elevation / (90.0 / self.bands)).astype(int), 0, self.bands - 1)
        ring = np.searchsorted(np.asarray(self.splits), distance, side="right")
        return np.asarray((sector * self.bands + band) * (len(self.splits) + 1) + ring)

    def cell(self, index: int) -> Cell:
        """The ranges of cell `index` (0 <= index < `size`)."""
        if not 0 <= index < self.size:
            raise ValueError(f"cell index {index} outside 0..{self.size - 1}")
        rings = len(self.splits) + 1
        sector, rest = divmod(index, self.bands * rings)
        band, ring = divmod(rest, rings)
        width, height = 360.0 / self.sectors, 90.0 / self.bands
        a0 = sector * width - width / 2
        a0 = a0 - 360.0 if a0 >= 180.0 else a0
        edges = (0.0, *self.splits, math.inf)
        return Cell(
            index,
            (a0, a0 + width),
            (band * height, (band + 1) * height),
            (edges[ring], edges[ring + 1]),
        )

    def shares(self, centres: np.ndarray) -> dict[int, float]:
        """Sampled camera centres [S, 3] cm -> each cell's share of them, largest first."""
        cells, counts = np.unique(self.indices(centres), return_counts=True)
        order = np.argsort(-counts, kind="stable")
        total = float(counts.sum())
        return {int(cells[i]): float(counts[i]) / total for i in order}
