"""The object frame and the order of the object's four corners.

Object frame: origin at the centre of the object rectangle, the object in z = 0, x along its
width (right on the front-on texture), y towards the top of its texture, z towards the side that
shows the texture (the viewer). Units: cm.

The corners are always listed in `CORNER_ORDER`: (-X,-Y), (+X,-Y), (+X,+Y), (-X,+Y), i.e.
bottom-left, bottom-right, top-right, top-left of the front-on texture. This is also the order
of the ONNX `corners` output, of the data sets' corner columns and of the service's answer.
"""

from __future__ import annotations

import numpy as np

#: Signs (x, y) of the four corners, in the order every corner list uses.
CORNER_SIGNS: tuple[tuple[int, int], ...] = ((-1, -1), (1, -1), (1, 1), (-1, 1))
#: The same order in words, for docs, model cards and help texts.
CORNER_ORDER = "(-X,-Y), (+X,-Y), (+X,+Y), (-X,+Y)"


def object_corners(width_cm: float, height_cm: float, z: bool = False) -> np.ndarray:
    """Corners of a `width_cm` x `height_cm` object, (4, 2) cm in `CORNER_ORDER`.

    With `z`, (4, 3) points of the object plane (z = 0), as OpenCV's solvePnP takes them.
    """
    w, h = width_cm / 2.0, height_cm / 2.0
    xy = np.array([(sx * w, sy * h) for sx, sy in CORNER_SIGNS], dtype=np.float64)
    return np.column_stack([xy, np.zeros(4)]) if z else xy


def texture_to_object(
    texture_size: tuple[int, int], width_cm: float, height_cm: float
) -> np.ndarray:
    """Affine map (3, 3) from texture pixels (u, v) to object-plane cm (x, y).

    The texture covers the object rectangle front-on, +y up: pixel centres are at integer
    (u, v), so the left edge u = -0.5 is x = -w/2 and the top edge v = -0.5 is y = +h/2.
    """
    tw, th = texture_size
    sx, sy = width_cm / tw, height_cm / th
    return np.array(
        [[sx, 0.0, sx * 0.5 - width_cm / 2], [0.0, -sy, height_cm / 2 - sy * 0.5], [0, 0, 1]]
    )
