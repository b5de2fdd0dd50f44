"""The 9 pose classes (SPEC section 3) and their description in words.

Class 0: the object is not in the image. Classes 1-8: the camera centre lies in one octant
around the object, in the object frame (origin at its centre, x along its width, y towards
the top of its texture, z towards the viewer, cm):

    quadrant 1: x >= 0, y >= 0    2: x < 0, y >= 0    3: x < 0, y < 0    4: x >= 0, y < 0
    class = quadrant (near, z < z_split) or quadrant + 4 (far, z >= z_split)
"""

from __future__ import annotations

from typing import Literal, TypedDict

NUM_CLASSES = 9

# (x side, y side) of each quadrant 1..4.
_QUADRANT_SIDES: dict[int, tuple[Literal["+", "-"], Literal["+", "-"]]] = {
    1: ("+", "+"),
    2: ("-", "+"),
    3: ("-", "-"),
    4: ("+", "-"),
}


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
    depth: Literal["near", "far"] = "near" if class_id <= 4 else "far"
    x, y = _QUADRANT_SIDES[(class_id - 1) % 4 + 1]
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
