"""How the labelled regions hold up when posed again from four corners, exact and noisy.

Each image of a data set with the object in view is posed again from its labelled corners
(labels.csv `corner_x0..y3`, px of the set's images) with its own camera (the labels' `fx`,
`fy`, `cx`, `cy` of a real photo, else the SPEC camera times `focal_scale`; and `k1`, the one-
coefficient radial lens the corner network models), by the service's `solve_pose`, and classed
as the labels are (SPEC section 3): exactly, then with the corners moved by Gaussian noise of
0.25 / 0.5 / 1 px per coordinate (px of the 160-px-wide network input; 0.5 is the default
model's noise on real photos, `service.core.pose.CORNER_NOISE_INPUT_PX`; 16 seeded draws each).
With the margin of the camera centres from the region boundaries, this says how sensitive a
set's regions are to its corners: near a boundary a fraction of a pixel decides. It is not a
bound on a model: a real photo's labels came from more of its corners and its full lens model,
which these four corners and k1 do not reproduce exactly (the exact row), and a model fits its
own lens.

    python scripts/region_sensitivity.py runs/charuco/data/real-s2-b0 runs/default/data/real-s2-b0 \
        --split test --out docs/region_sensitivity.md
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from service.core.dataset import DatasetError, load_dataset
from service.core.frame import object_corners
from service.core.geometry import intrinsics
from service.core.pose import Camera, solve_pose
from service.core.regions import Z_SPLIT_CM, boundary_margin_cm, pose_class
from train.markdown import table, written_by

NOISE_PX = (0.25, 0.5, 1.0)  # per coordinate, px of a 160-px-wide image
DRAWS = 16


def camera_of(row: dict[str, str], size: tuple[int, int]) -> Camera:
    """A labels.csv row -> the camera of its image of `size` (W, H): its fx, fy, cx, cy (else
    the SPEC camera times `focal_scale`) and only its k1 (OpenCV's model)."""
    if row.get("fx"):
        fx, fy, cx, cy = (float(row[k]) for k in ("fx", "fy", "cx", "cy"))
    else:
        K = intrinsics(size, float(row.get("focal_scale") or 1.0))
        fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    return Camera(fx, size, fy, cx, cy, (float(row.get("k1") or 0.0), 0.0, 0.0, 0.0, 0.0))


def posed_class(corners: np.ndarray, obj: np.ndarray, camera: Camera, z_split: float) -> int:
    """Corners [4, 2] px -> the class of the camera centre they are posed at (`solve_pose`:
    the service's IPPE, the camera on the printed side)."""
    centre = solve_pose(corners, obj, camera).centre
    return int(pose_class(centre[None], z_split)[0])


def section(folder: Path, split: str) -> list[str]:
    """One data set's section of the page: its margins and the table of class % re-posed."""
    data = load_dataset(folder, split=None if split == "all" else split)
    profile = data.manifest.get("profile") or {}
    if "width_cm" not in profile or "corner_x0" not in (data.rows[0] if data.rows else {}):
        raise DatasetError(f"{folder} has no object size or no labelled corners")
    obj = object_corners(float(profile["width_cm"]), float(profile["height_cm"]), z=True)
    z_split = float(profile.get("z_split_cm", Z_SPLIT_CM))
    size = (int(data.manifest["size"][0]), int(data.manifest["size"][1]))
    rows = [r for r in data.rows if int(r["class"]) > 0]
    if not rows:
        raise DatasetError(f"no image of {folder} ({split}) shows the object")
    labels = np.array([int(r["class"]) for r in rows])
    centres = np.array([[float(r[k]) for k in ("cam_x", "cam_y", "cam_z")] for r in rows])
    margins = boundary_margin_cm(centres, z_split)
    rng = np.random.default_rng(0)
    right = {noise: np.zeros(len(rows)) for noise in (0.0, *NOISE_PX)}
    for i, row in enumerate(rows):
        corners = np.array([[float(row[f"corner_{a}{k}"]) for a in "xy"] for k in range(4)])
        camera = camera_of(row, size)
        for noise, hits in right.items():
            draws = 1 if noise == 0 else DRAWS
            jitter = rng.normal(0.0, noise * size[0] / 160.0, (draws, 4, 2))
            hits[i] = np.mean(
                [posed_class(corners + d, obj, camera, z_split) == labels[i] for d in jitter]
            )
    bands = {
        "margin 0-2 cm": margins < 2,
        "margin 2-5 cm": (margins >= 2) & (margins < 5),
        "margin 5+ cm": margins >= 5,
    }
    shares = ", ".join(f"{100 * b.mean():.0f} % at {name}" for name, b in bands.items())
    cells = [
        [
            "exact" if noise == 0 else f"+ {noise:g} px noise",
            *(f"{100 * hits[b].mean():.1f}" if b.any() else "-" for b in bands.values()),
            f"{100 * hits.mean():.1f}",
        ]
        for noise, hits in right.items()
    ]
    return [
        f"## {folder.name} ({profile.get('name', '?')}, {split} split)",
        "",
        f"{len(rows)} images with the object; {shares}.",
        "",
        *table(["corners", *bands, "all"], cells),
        "",
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", type=Path, nargs="+", help="data set folders (labels.csv)")
    parser.add_argument("--split", default="test", help="train, val, test or all")
    parser.add_argument("--out", type=Path, help="also write the page here (Markdown)")
    args = parser.parse_args()
    folders = " ".join(str(f) for f in args.data)
    lines = [
        "# How the labelled regions hold up when posed again from the labelled corners",
        "",
        written_by(f"python scripts/region_sensitivity.py {folders} --split {args.split}")
        + " Class % of the images with the object, posed (IPPE, the camera on the printed "
        "side) from the labelled corners with each image's own fx and k1 (the lens the "
        "corner network models), exactly and "
        "with Gaussian noise per coordinate (px of a 160-px-wide input; 16 draws), by the "
        "camera centre's margin from the region boundaries (module doc).",
        "",
    ]
    try:
        for folder in args.data:
            lines += section(folder, args.split)
    except DatasetError as exc:
        sys.exit(f"error: {exc}")
    if args.out:
        args.out.write_text("\n".join(lines), encoding="utf-8")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
