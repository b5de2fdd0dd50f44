"""The region rule: the 9 pose classes of a camera centre (SPEC sections 3-4), and in words.

Class 0: the object is not in the image. Classes 1-8: the camera centre lies in one octant
around the object, in the object frame (`service.core.frame`, cm):

    quadrant 1: x >= 0, y >= 0    2: x < 0, y >= 0    3: x < 0, y < 0    4: x >= 0, y < 0
    class = quadrant (near, z < z_split) or quadrant + 4 (far, z >= z_split)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, TypedDict

import numpy as np
from numpy.typing import ArrayLike, NDArray

NUM_CLASSES = 9
#: The default near / far split (SPEC section 3), cm along the object's z axis.
Z_SPLIT_CM = 60.0
#: Signs (x, y) of the camera centre in quadrant 1..4 (index 0 = quadrant 1).
QUADRANT_SIGNS: tuple[tuple[int, int], ...] = ((1, 1), (-1, 1), (-1, -1), (1, -1))


@dataclass(frozen=True)
class RegionGeometry:
    """Where cameras may be and how their centres map to classes (SPEC sections 3-4), cm.

    The x/y split is at 0; `z_split_cm` separates near (class 1-4) from far (class 5-8);
    camera centres live in the axis-aligned box [box_min, box_max].
    """

    z_split_cm: float = Z_SPLIT_CM
    box_min: tuple[float, float, float] = (-36.86, -36.86, 10.68)
    box_max: tuple[float, float, float] = (36.86, 36.86, 92.40)

    def contains(self, points: ArrayLike) -> NDArray[np.bool_]:
        """Which of `points` (N, 3) lie inside the box (borders included) -> bool (N,)."""
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        lo, hi = np.asarray(self.box_min), np.asarray(self.box_max)
        return np.all((p >= lo) & (p <= hi), axis=1)


def pose_class(c: ArrayLike, z_split_cm: float) -> NDArray[np.int64]:
    """Class 1..8 of camera centre(s) `c` (..., 3) cm in the object frame -> int64 (...)."""
    p = np.asarray(c, dtype=float)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    quadrant = np.where(y >= 0, np.where(x >= 0, 1, 2), np.where(x < 0, 3, 4)).astype(np.int64)
    return quadrant + np.where(z >= z_split_cm, 4, 0).astype(np.int64)


#: The spread of a pose's class probabilities (`pose_probabilities`), x the camera's distance
#: for the x/y side and x |z| for near/far: the corner network's (`side_spread`,
#: `depth_spread` of train/network/keypoint.py).
SIDE_SPREAD, DEPTH_SPREAD = 0.08, 0.08


def pose_probabilities(c: ArrayLike, z_split_cm: float, present: float) -> NDArray[np.float64]:
    """A camera centre `c` (3,) cm in the object frame and P(object present) -> the 9 class
    probabilities float64 (9,): P(x >= 0), P(y >= 0) and P(z < z_split) as normal CDFs
    around the centre (spreads `SIDE_SPREAD` x the distance, `DEPTH_SPREAD` x |z|), class 0
    1 - present. Their largest of classes 1-8 is `pose_class(c)`."""
    x, y, z = (float(v) for v in np.asarray(c, dtype=float).reshape(3))
    side = SIDE_SPREAD * max(math.sqrt(x * x + y * y + z * z), 1.0)
    px, py = _cdf(x / side), _cdf(y / side)
    near = _cdf((z_split_cm - z) / (DEPTH_SPREAD * max(abs(z), 1.0)))
    sides = {1: (px, py), -1: (1 - px, 1 - py)}
    quadrants = [sides[sx][0] * sides[sy][1] for sx, sy in QUADRANT_SIGNS]
    return np.array(
        [1 - present] + [present * near * q for q in quadrants]
        + [present * (1 - near) * q for q in quadrants]
    )  # fmt: skip


def _cdf(t: float) -> float:
    """The standard normal CDF at `t`."""
    return 0.5 * (1.0 + math.erf(t / math.sqrt(2.0)))


def quadrant_of_class(class_id: ArrayLike) -> NDArray[np.int64]:
    """Quadrant 1..4 of class(es) 1..8 (the x/y side, distance ignored); 0 for class 0."""
    k = np.asarray(class_id, dtype=np.int64)
    return np.where(k == 0, 0, (k - 1) % 4 + 1)


def is_far(class_id: ArrayLike) -> NDArray[np.bool_]:
    """Whether class(es) 0..8 lie in the far half (z >= z_split): classes 5-8."""
    return np.asarray(class_id) > 4


def boundary_margin_cm(c: ArrayLike, z_split_cm: float) -> NDArray[np.float64]:
    """Distance (cm) of camera centre(s) `c` (..., 3) from the nearest region boundary, the
    planes x = 0, y = 0 and z = z_split of the object frame -> float64 (...)."""
    p = np.asarray(c, dtype=float)
    return np.minimum(
        np.minimum(np.abs(p[..., 0]), np.abs(p[..., 1])), np.abs(p[..., 2] - z_split_cm)
    )


class Region(TypedDict):
    """A class in words. For class 0 only `present` and `label` carry meaning."""

    present: bool
    depth: Literal["near", "far"] | None
    x: Literal["+", "-"] | None
    y: Literal["+", "-"] | None
    label: str


def region_of_class(class_id: int) -> Region:
    """Describe class 0..8 in words, e.g. 5 -> far, x+, y+ ("far, x+, y+")."""
    if not 0 <= class_id < NUM_CLASSES:
        raise ValueError(f"class id must be in 0..8, got {class_id}")
    if class_id == 0:
        return Region(present=False, depth=None, x=None, y=None, label="object not in view")
    depth: Literal["near", "far"] = "far" if is_far(class_id) else "near"
    sx, sy = QUADRANT_SIGNS[int(quadrant_of_class(class_id)) - 1]
    x: Literal["+", "-"] = "+" if sx > 0 else "-"
    y: Literal["+", "-"] = "+" if sy > 0 else "-"
    return Region(present=True, depth=depth, x=x, y=y, label=f"{depth}, x{x}, y{y}")


def class_descriptions(z_split_cm: float) -> list[str]:
    """One sentence per class 0..8 saying where the camera centre is, for model cards."""
    out = ["the object is not in the image"]
    for k in range(1, NUM_CLASSES):
        r = region_of_class(k)
        rel = f"z < {z_split_cm:g} cm" if r["depth"] == "near" else f"z >= {z_split_cm:g} cm"
        xs = "x >= 0" if r["x"] == "+" else "x < 0"
        ys = "y >= 0" if r["y"] == "+" else "y < 0"
        out.append(f"{r['label']}: camera centre at {xs}, {ys}, {rel} (object frame)")
    return out
