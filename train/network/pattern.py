"""What the corner network reads of an object's texture: templates on a grid of cells.

The corner network finds the object's four corners up to a half turn (the rectangle's shape
alone cannot tell corner 0 from corner 2). The texture tells them apart: sampled through the
corners' homography at the centres of a grid of cells, the image correlates with the texture's
template in the true order and not in the half-turned one (`train.network.corners.parity`).
The same template, at more points, is what the corners are aligned to
(`train.network.align.TextureAlign`).

For the 10 x 7-square chessboard the cells are its squares and the template is its checker
(+1 white, -1 black): a half turn inverts it, so the sign of one correlation decides, and the
analytic checker (also blurred as SPEC blur 3 blurs it) is used exactly as before. Whether a
texture is that checker is measured from the texture, not named: its cell means at the
10 x 7 square centres are black and white and alternate.

Coordinates: (s, t) in the unit square of the object, (0, 0) at corner 0 (-X, -Y), s along
+x, t along +y (towards the top of the texture, whose row 0 is the top).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from service.core.paths import REPO_ROOT

#: The chessboard's squares along x, y.
CHECKER_SQUARES = (10, 7)
#: Cells along the longer side of a texture that is not the checker.
CELLS_LONG_SIDE = 10


@dataclass(frozen=True)
class Pattern:
    """An object's texture as the corner network reads it.

    `grey` float32 [h, w] in [0, 1] (row 0 the top of the texture), `cells` (along x, y) the
    grid of its templates, `checker` True where it is the 10 x 7 chessboard's checker.
    """

    grey: np.ndarray
    cells: tuple[int, int]
    checker: bool

    def sample(self, st: np.ndarray, blur_cells: float = 0.0) -> np.ndarray:
        """The texture at unit-square points `st` [P, 2] (module doc), blurred by a Gaussian of
        `blur_cells` cells, as a template [P]: zero mean, unit RMS over the points."""
        grey = self.grey
        h, w = grey.shape
        if blur_cells > 0:
            sigma = blur_cells * w / self.cells[0]
            grey = cv2.GaussianBlur(grey, (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)
        st = np.asarray(st, dtype=np.float32).reshape(-1, 2)
        map_u = (st[:, 0] * w - 0.5).reshape(1, -1)
        map_v = ((1.0 - st[:, 1]) * h - 0.5).reshape(1, -1)
        values = cv2.remap(grey, map_u, map_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        values = values.ravel().astype(np.float64)
        values -= values.mean()
        return values / max(float(np.sqrt((values**2).mean())), 1e-6)

    def cell_centres(self) -> np.ndarray:
        """(s, t) [cx * cy, 2] of the cell centres, s fastest (the order of the checker)."""
        i, j = np.meshgrid(np.arange(self.cells[0]), np.arange(self.cells[1]), indexing="xy")
        return np.stack([(i + 0.5) / self.cells[0], (j + 0.5) / self.cells[1]], -1).reshape(-1, 2)


def _is_checker(grey: np.ndarray) -> bool:
    """Whether the texture is the 10 x 7 chessboard: its squares' centres are black or white,
    alternating, and the square at corner 0 is black."""
    probe = Pattern(grey, CHECKER_SQUARES, False)
    h, w = grey.shape
    st = probe.cell_centres()
    u = np.clip((st[:, 0] * w).astype(int), 0, w - 1)
    v = np.clip(((1 - st[:, 1]) * h).astype(int), 0, h - 1)
    means = grey[v, u]
    i, j = np.meshgrid(*(np.arange(n) for n in CHECKER_SQUARES), indexing="xy")
    white = ((i + j) % 2 == 1).ravel()
    return bool(np.all(means[white] > 0.7) and np.all(means[~white] < 0.3))


def pattern_from_texture(rgb: np.ndarray, width_cm: float, height_cm: float) -> Pattern:
    """The pattern of a texture RGB uint8 [h, w, 3] covering a `width_cm` x `height_cm`
    object: the checker where it is one, else cells about square, `CELLS_LONG_SIDE` along the
    longer side."""
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0
    if abs(width_cm / height_cm - CHECKER_SQUARES[0] / CHECKER_SQUARES[1]) < 1e-3 and _is_checker(
        grey
    ):
        return Pattern(grey, CHECKER_SQUARES, True)
    long_side = max(width_cm, height_cm)
    cells = (
        max(2, round(CELLS_LONG_SIDE * width_cm / long_side)),
        max(2, round(CELLS_LONG_SIDE * height_cm / long_side)),
    )
    return Pattern(grey, cells, False)


def texture_of(profile: dict[str, Any] | None) -> np.ndarray | None:
    """The picture RGB uint8 [h, w, 3] of a data set manifest's profile (`texture`
    repo-relative or absolute); None without a profile or a texture."""
    if not profile or not profile.get("texture"):
        return None
    path = REPO_ROOT / str(profile["texture"])
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise ValueError(f"cannot read the profile's texture {path}")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def pattern_of(profile: dict[str, Any] | None) -> Pattern | None:
    """The pattern of a data set manifest's profile (`texture`, `width_cm`, `height_cm`);
    None without a profile or a texture (the network's default, the chessboard)."""
    rgb = texture_of(profile)
    if rgb is None or profile is None:
        return None
    return pattern_from_texture(rgb, float(profile["width_cm"]), float(profile["height_cm"]))
