"""The `pose` and `cell` of an answer, from the object's corners (docs/pose.md).

The corners are the network's, in px of the uploaded image; the object's size is its model
card's profile. The focal length is the request's where it knows one (`KnownFocal`: query,
camera, EXIF, stream), else a joint fit over a same-camera request's photos, else the one
view's estimate (`service.core.pose.estimate_focal`), which also gives the range of focal
lengths, and so of distances, the view allows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from service.core.cells import RegionGrid
from service.core.frame import object_corners
from service.core.pose import FOCAL_PRIOR, Camera, corner_noise_px, estimate_focal, solve_pose
from service.pipeline.focal import KnownFocal
from service.pipeline.results import Cell, CellShare, FocalSource, Lens, Pose

#: Poses sampled for a cell's probabilities: the corners' noise and the focal range drawn.
CELL_SAMPLES = 64
#: A neighbouring cell holding less than this share of the samples is not named.
NEIGHBOUR_SHARE = 0.02


@dataclass(frozen=True)
class Focal:
    """The focal length a pose takes: its camera, where it came from, and the range of fx px
    (lo, hi) the views allow where it was estimated (None: known)."""

    camera: Camera
    source: FocalSource
    interval: tuple[float, float] | None = None
    noise_px: float | None = None  # the corners' noise per coordinate, px (None: the network's)


def focal_of(
    corners: np.ndarray,
    size: tuple[int, int],
    size_cm: tuple[float, float],
    known: KnownFocal | None,
    prior: float = FOCAL_PRIOR,
    noise_px: float | None = None,
) -> Focal:
    """The focal length of one image of `size` (W, H) px whose pinhole corners [4, 2] px
    have `noise_px` of noise per coordinate (None: the network's, `corner_noise_px`):
    `known`'s (its lens left out: the corners are a pinhole's), else estimated from the
    corners with the model's `prior` (x the SPEC camera's, `PoseModel.focal_prior`)."""
    if known is not None:
        return Focal(replace(known.camera(size), dist=None), known.source, None, noise_px)
    obj = object_corners(*size_cm, z=True)
    fx, interval = estimate_focal(corners, obj, size, prior, noise_px)
    return Focal(Camera(fx, size), "estimated", interval, noise_px)


def _round(values: np.ndarray | list[float], digits: int = 3) -> list[float]:
    return [round(float(v), digits) for v in values]


def pose_of(
    corners: np.ndarray, size_cm: tuple[float, float], focal: Focal, lens: Lens = "none"
) -> Pose:
    """Pinhole corners [4, 2] px of the uploaded image (`lens` undone), the object's size
    (W, H) cm and the focal length -> the answer's `pose`."""
    obj = object_corners(*size_cm, z=True)
    pose = solve_pose(corners, obj, focal.camera)
    distances = None
    if focal.interval is not None:
        ends = [
            solve_pose(corners, obj, _with_fx(focal.camera, f)).distance_cm for f in focal.interval
        ]
        distances = _round(sorted([min(ends + [pose.distance_cm]), max(ends + [pose.distance_cm])]))
    return Pose(
        camera_cm=_round(pose.centre),
        distance_cm=round(pose.distance_cm, 3),
        azimuth_deg=round(pose.azimuth_deg, 3),
        elevation_deg=round(pose.elevation_deg, 3),
        rvec=_round(pose.rvec, 6),
        tvec_cm=_round(pose.tvec),
        fx=round(focal.camera.fx, 3),
        fx_source=focal.source,
        fx_range=None if focal.interval is None else _round(list(focal.interval)),
        distance_range_cm=distances,
        residual_px=round(pose.residual_px, 3),
        lens=lens,
    )


def _with_fx(camera: Camera, fx: float) -> Camera:
    """`camera` with the focal length `fx` (fy alike)."""
    return Camera(fx, camera.size, None, camera.cx, camera.cy, camera.dist)


def cell_of(
    grid: RegionGrid,
    corners: np.ndarray,
    size_cm: tuple[float, float],
    focal: Focal,
) -> Cell:
    """The pose's cell of `grid` and the share of `CELL_SAMPLES` poses in it and its
    neighbours: the corners moved by their noise (`corner_noise_px`) and, where fx is
    estimated, fx drawn log-uniformly over its range (a fixed seed: the same image gets the
    same answer)."""
    obj = object_corners(*size_cm, z=True)
    pose = solve_pose(corners, obj, focal.camera)
    rng = np.random.default_rng(0)
    noise = corner_noise_px(focal.camera.size) if focal.noise_px is None else focal.noise_px
    jitter = rng.normal(0.0, noise, (CELL_SAMPLES, 4, 2))
    lo, hi = focal.interval or (focal.camera.fx, focal.camera.fx)
    fxs = np.exp(rng.uniform(math.log(lo), math.log(hi), CELL_SAMPLES))
    centres = np.array(
        [
            solve_pose(corners + dq, obj, _with_fx(focal.camera, f)).centre
            for dq, f in zip(jitter, fxs, strict=True)
        ]
    )
    index = int(grid.indices(pose.centre[None])[0])
    shares = grid.shares(centres)
    cell = grid.cell(index)
    neighbours = [
        CellShare(index=i, probability=round(p, 3))
        for i, p in shares.items()
        if i != index and p >= NEIGHBOUR_SHARE
    ]
    far = cell.distance_cm[1]
    return Cell(
        grid=str(grid),
        index=index,
        azimuth_deg=list(cell.azimuth_deg),
        elevation_deg=list(cell.elevation_deg),
        distance_cm=[cell.distance_cm[0], None if math.isinf(far) else far],
        label=cell.label,
        probability=round(shares.get(index, 0.0), 3),
        neighbours=neighbours,
    )
