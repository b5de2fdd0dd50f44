"""Measure the corner network's camera-model constants on the corpus's val (and train)
sources and on renders of the SPEC's own camera, and write docs/camera_model.md.

The geometry after the corners has no weights: the focal-length prior, the radial-distortion
prior, the principal point and the pixel aspect are choices, made on the real val sources
(cameras never used for training or test) with the train sources, the val split of the
SPEC-camera renders (`spec-s2-b0..3`, profile `chessboard-spec`) and that of long-lens renders
(`tele-s2-b0..3`, profile `chessboard-tele`: 1.2-2 x the SPEC focal length, beyond every
corpus camera) as second checks. This
script runs the network once per photo (corners, presence, parity), then only the geometry
per variant:

* class accuracy per split and blur level for camera models (square pixels or the input's
  pixel aspect, radial prior k1);
* on the labelled corners of the photos that are not 4:3: the camera centre's depth error
  and the self-calibrated focal length against the calibrated one, with and without the
  pixel aspect;
* the val board photos turned to portrait, squashed to 160x120 or turned back first
  (`service.core.preprocess.NetworkFrame`);
* the focal-length prior and its weight; the bounds of the estimate; the principal point;
* the focal-length prior shortened by a strong barrel distortion (`corner_net.BARREL_LIMIT`),
  with the alignment's k1 range as the code has it and as it was before (down to -0.6);
* what limits the answer: the network's corners, the labelled ones or the chessboard
  detector's (the comparison's peer), each with the self-calibrated camera or with the
  photo's calibrated one (focal length, principal point, k1, pixel aspect from labels.csv),
  presence from the network.

Usage (after `scripts/train_default.sh`, which makes the run and the data sets; a shipped
model's ONNX graph works too, e.g. models/chessboard-corners-160x120.onnx, with the data sets
of its step 1):
    .venv/bin/python scripts/camera_model_choices.py \
        runs/default/runs/chessboard-corners-160x120/best.pt runs/default/data
"""

from __future__ import annotations

import argparse
import csv
import sys
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import torch

from service.core.dataset import LoadedDataset, load_dataset, read_splits
from service.core.geometry import intrinsics
from service.core.inputs import SIZES
from service.core.paths import REPO_ROOT
from service.core.pose import FOCAL_BOUNDS
from service.core.preprocess import NetworkFrame, to_network_input
from service.core.profile import load_profile
from service.core.regions import Z_SPLIT_CM, pose_class
from train.compare.chessboard_peer import ENLARGE, enlarged_grey
from train.markdown import table, written_by
from train.network import corners as corner_net
from train.network.align import square_homography
from train.network.corners import CornerNet
from train.network.fit import load_network, to_input
from train.network.onnx_weights import corner_net_from_onnx
from train.real.corners import detect_chessboard
from train.real.label import ObjectFinder
from train.real.realset import read_rgb

RADIAL = (0.0, -0.1, -0.2, -0.25, -0.3, -0.4)
DEFAULT_PRIOR_WEIGHT, RADIAL_PRIOR = corner_net.FOCAL_PRIOR_WEIGHT, corner_net.RADIAL_PRIOR
FOCAL_PRIORS = (0.6, 0.7, 0.8, 0.85, 0.9, 0.95, 1.0, 1.1)  # x the SPEC camera's focal length
PRIOR_WEIGHTS = (0.001, 0.003, 0.01, 0.1)
FOCAL_UPPER = (1.2, 1.5, 2.0)  # upper bounds of the estimate tried, x the SPEC camera's
BARREL_LIMITS = (-0.3, -0.35, -0.4, -0.45, -0.5, -0.6)  # `corner_net.BARREL_LIMIT` tried
K1_LOWER = -0.6  # the lower end of the alignment's k1 range before 3.8.0
# `limits_table`: where the corners come from
CORNER_SOURCES = {
    "network": "network corners",
    "labelled": "labelled corners",
    "detector": "detector's corners (4x, else the network's)",
}
CORPUS = REPO_ROOT / "train/assets/real/corpus"
# `_caches`: real val and train sources, SPEC-camera and long-lens renders
SPLITS = ("val", "train", "spec", "tele")
SPLIT_HEADER = [
    "val sources",
    "train sources",
    "SPEC-camera renders (val split)",
    "long-lens renders (val split)",
]


class Cached:
    """The network's part of the answer on one data set split (`CornerNet.observe`, with
    each image's pixel aspect): aligned corners [N, 4, 2], their parity [N], P(present) [N],
    the lens's k1 the alignment fitted [N]; pixel aspect [N], labels [N], the labelled
    corners [N, 4, 2] (nan where none) and the labels.csv rows."""

    def __init__(self, net: CornerNet, data: LoadedDataset) -> None:
        x = to_input(data.images)
        self.aspect = torch.from_numpy(data.pixel_aspect())
        with torch.no_grad():
            parts = [
                net.observe(x[i : i + 128], self.aspect[i : i + 128]) for i in range(0, len(x), 128)
            ]
        self.q, self.parity, self.present, self.k1 = (
            torch.cat([getattr(p, f) for p in parts])
            for f in ("corners", "parity", "present", "k1")
        )
        self.labels = data.labels
        self.rows = data.rows
        self.labelled = torch.from_numpy(data.corners())
        self.images = data.images
        self._detected: torch.Tensor | None = None

    def accuracy(self, net: CornerNet, use_aspect: bool, k1: float | None = None) -> float:
        """Class accuracy (%) with the camera model (pixel aspect or square pixels; k1 fixed,
        or None: each image's fitted k1, the code's)."""
        if k1 is not None:
            net.radial_prior.fill_(k1)
        aspect = self.aspect if use_aspect else torch.ones_like(self.aspect)
        with torch.no_grad():
            fitted = self.k1 if k1 is None else None
            pk = net.pose_classes(self.q, self.parity, aspect, None, fitted)
        net.radial_prior.fill_(RADIAL_PRIOR)
        return self._percent(pk)

    def _percent(self, pk: torch.Tensor) -> float:
        """Class accuracy (%) of P(class 1..8 | present) [N, 8] with the network's presence."""
        pr = self.present[:, None]
        predicted = torch.cat([1 - pr, pr * pk], 1).argmax(1).numpy()
        return 100.0 * float(np.mean(predicted == self.labels))

    def detector_corners(self, net: CornerNet) -> torch.Tensor:
        """The board's four corners [N, 4, 2] px in the object's order as OpenCV's chessboard
        detector sees them, NaN where it finds no board: the comparison's peer (the image
        enlarged 4x, cubic; `detect_chessboard`), the outline (`ObjectFinder.corners_xy`, the
        labels' order) through the homography of its inner-corner grid. Computed once."""
        if self._detected is None:
            finder = ObjectFinder(load_profile("chessboard"))
            assert finder.pattern is not None  # the chessboard profile has one
            outline_cm = finder.corners_xy().reshape(-1, 1, 2)
            f, (cu, cv) = float(net.focal) * ENLARGE, (net.principal.double().numpy() + 0.5)
            A = np.array([[f, 0.0, cu * ENLARGE - 0.5], [0.0, f, cv * ENLARGE - 0.5], [0, 0, 1]])
            found = torch.full((len(self.images), 4, 2), float("nan"))
            for i, rgb in enumerate(self.images):
                grey = enlarged_grey(rgb, ENLARGE)
                grid = detect_chessboard(grey, finder.pattern, lambda p: p, A)
                if grid is None:
                    continue
                H, _ = cv2.findHomography(grid.object_xy, grid.image_uv)
                if H is None:
                    continue
                outline_px = cv2.perspectiveTransform(outline_cm, H).reshape(4, 2)
                found[i] = torch.from_numpy((outline_px + 0.5) / ENLARGE - 0.5)
            self._detected = found
        return self._detected

    def accuracy_from(self, net: CornerNet, corners: str, calibrated: bool) -> float:
        """Class accuracy (%) from the network's `corners`, the labelled ones or those of the
        chessboard detector (`detector_corners`; the network's where either has none), in the
        object's order, with the code's self-calibrated camera (and the k1 the alignment
        fitted) or (`calibrated`) each photo's calibrated one (labels.csv: fx, fy, cx, cy, k1
        in network pixels; the self-calibrated one where a row has none)."""
        if corners == "labelled":
            given = self.labelled
        elif corners == "detector":
            given = self.detector_corners(net)
        else:
            given = torch.full((len(self.rows), 4, 2), float("nan"))
        pk = torch.zeros(len(self.rows), 8)
        code = _camera(net)
        for i, row in enumerate(self.rows):
            q, parity = self.q[i : i + 1], self.parity[i : i + 1]
            if bool(torch.isfinite(given[i]).all()):
                q, parity = given[i : i + 1].to(q.dtype), torch.ones(1)
            aspect, k1 = self.aspect[i : i + 1], self.k1[i : i + 1]
            if calibrated and row.get("fx"):
                fx, fy = float(row["fx"]), float(row["fy"])
                net.self_calibrate.fill_(0.0)
                net.focal.fill_(fx)
                net.principal.copy_(torch.tensor([float(row["cx"]), float(row["cy"])]))
                net.radial_prior.fill_(float(row.get("k1") or 0.0))
                aspect, k1 = torch.tensor([fy / fx]), None
            with torch.no_grad():
                pk[i] = net.pose_classes(q, parity, aspect, None, k1)[0]
            _set_camera(net, code)
        return self._percent(pk)


CAMERA_BUFFERS = ("focal", "principal", "self_calibrate", "radial_prior")


def _camera(net: CornerNet) -> dict[str, torch.Tensor]:
    """A copy of `net`'s camera-model buffers, for `_set_camera` to put back."""
    return {name: getattr(net, name).clone() for name in CAMERA_BUFFERS}


def _set_camera(net: CornerNet, camera: dict[str, torch.Tensor]) -> None:
    for name, value in camera.items():
        getattr(net, name).copy_(value)


def _caches(net: CornerNet, data_dir: Path) -> dict[tuple[str, int], Cached]:
    """The network's answers by (split, blur): the val and train splits of real-s2-b0..3 and,
    as splits "spec" and "tele", the val splits of the SPEC-camera renders spec-s2-b0..3 and
    of the long-lens renders tele-s2-b0..3."""
    cache = {
        (split, b): Cached(net, load_dataset(data_dir / f"real-s2-b{b}", split=split))
        for split in ("val", "train")
        for b in range(4)
    }
    for kind in ("spec", "tele"):
        for b in range(4):
            data = load_dataset(data_dir / f"{kind}-s2-b{b}", split="val")
            cache[(kind, b)] = Cached(net, data)
    return cache


def _cells(cache: dict[tuple[str, int], Cached], accuracy: Callable[[Cached], float]) -> list[str]:
    """One table cell per split (`SPLITS`): `accuracy(cached)` at blur 0 / 1 / 2 / 3
    and their mean."""
    cells = []
    for split in SPLITS:
        accs = [accuracy(cache[(split, b)]) for b in range(4)]
        cells.append(" / ".join(f"{a:.1f}" for a in accs) + f" (mean {np.mean(accs):.1f})")
    return cells


def accuracy_table(net: CornerNet, cache: dict[tuple[str, int], Cached]) -> list[list[str]]:
    rows = []
    for use_aspect in (False, True):
        for k1 in RADIAL:
            name = ("pixel aspect" if use_aspect else "square pixels") + f", k1 = {k1:g}"
            rows.append([name, *_cells(cache, lambda c, a=use_aspect, k=k1: c.accuracy(net, a, k))])
    fitted = "pixel aspect, k1 fitted per image (the code's)"
    rows.append([fitted, *_cells(cache, lambda c: c.accuracy(net, True))])
    return rows


def focal_prior_table(net: CornerNet, cache: dict[tuple[str, int], Cached]) -> list[list[str]]:
    """Class accuracy per focal-length prior and prior weight (pixel aspect, k1 of the code)."""
    code = _camera(net)
    spec_f = float(net.focal) / corner_net.FOCAL_PRIOR
    rows = []
    for prior in FOCAL_PRIORS:
        for weight in PRIOR_WEIGHTS:
            net.focal.fill_(spec_f * prior)
            corner_net.FOCAL_PRIOR_WEIGHT = weight  # read by `focal_length` at each call
            name = f"{prior:g} x SPEC, weight {weight:g}"
            rows.append([name, *_cells(cache, lambda c: c.accuracy(net, True))])
    corner_net.FOCAL_PRIOR_WEIGHT = DEFAULT_PRIOR_WEIGHT
    _set_camera(net, code)
    return rows


def principal_point_table(net: CornerNet, cache: dict[tuple[str, int], Cached]) -> list[list[str]]:
    """Class accuracy with the principal point at the image centre (the code's) or at the
    SPEC camera's (80.05, 49.86 at 160x120: where the renders have it)."""
    code = _camera(net)
    rows = []
    for name, point in (
        ("image centre (the code's)", code["principal"]),
        ("the SPEC camera's", torch.from_numpy(intrinsics(net.size)[:2, 2]).float()),
    ):
        net.principal.copy_(point)
        rows.append([name, *_cells(cache, lambda c: c.accuracy(net, True))])
    _set_camera(net, code)
    return rows


def focal_bounds_table(net: CornerNet, cache: dict[tuple[str, int], Cached]) -> list[list[str]]:
    """Class accuracy with the focal-length estimate's upper bound at each of `FOCAL_UPPER`
    (the code's prior, weight, lower bound and k1)."""
    spec_f = float(net.focal) / corner_net.FOCAL_PRIOR
    code = net.focal_bounds.clone()
    rows = []
    for upper in FOCAL_UPPER:
        net.focal_bounds[1] = spec_f * upper
        name = f"{FOCAL_BOUNDS[0]:g}-{upper:g} x SPEC"
        rows.append([name, *_cells(cache, lambda c: c.accuracy(net, True))])
    net.focal_bounds.copy_(code)
    return rows


def barrel_limit_table(
    net: CornerNet, cache: dict[tuple[str, int], Cached], narrow: dict[tuple[str, int], Cached]
) -> list[list[str]]:
    """Class accuracy with no barrel limit and at each of `BARREL_LIMITS`, from the corners
    and k1 aligned with the code's k1 range (`cache`) and with the range down to `K1_LOWER`
    only (`narrow`)."""
    code = corner_net.BARREL_LIMIT
    lo, hi = net.align.k1_range
    rows = []
    for caches, k1_range in ((narrow, f"{K1_LOWER:g}..{hi:g}"), (cache, f"{lo:g}..{hi:g}")):
        for limit in (float("-inf"), *BARREL_LIMITS):
            corner_net.BARREL_LIMIT = limit  # read by `prior_focal` at each call
            name = f"k1 range {k1_range}, " + (
                "no limit" if limit == float("-inf") else f"limit {limit:g}"
            )
            rows.append([name, *_cells(caches, lambda c: c.accuracy(net, True))])
    corner_net.BARREL_LIMIT = code
    return rows


def limits_table(net: CornerNet, cache: dict[tuple[str, int], Cached]) -> list[list[str]]:
    """Class accuracy (%) per split and blur level from the network's, the labelled or the
    chessboard detector's corners, with the self-calibrated or the calibrated camera; and
    the board photos the network's presence misses."""
    rows = []
    for split in ("val", "train"):
        found: dict[str, list[float]] = {}
        missed = []
        for b in range(4):
            cached = cache[(split, b)]
            for corners in ("network", "labelled", "detector"):
                for calibrated in (False, True):
                    name = (
                        f"{CORNER_SOURCES[corners]}, "
                        f"{'calibrated' if calibrated else 'self-calibrated'} camera"
                    )
                    found.setdefault(name, []).append(
                        cached.accuracy_from(net, corners, calibrated)
                    )
            board = cached.labels > 0
            missed.append(
                f"{int((board & (cached.present.numpy() < 0.5)).sum())}/{int(board.sum())}"
            )
        for name, accs in found.items():
            rows.append([split, name, " / ".join(f"{a:.1f}" for a in accs)])
        rows.append([split, "board photos the presence misses", " / ".join(missed)])
    return rows


def labelled_corner_table(net: CornerNet, data_dir: Path) -> list[list[str]]:
    """Per camera that is not 4:3 (train and val): the camera centre from the labelled
    corners, square pixels against the pixel aspect."""
    rows = []
    for split in ("train", "val"):
        data = load_dataset(data_dir / "real-s2-b0", split=split)
        board = data.labels > 0
        q = torch.from_numpy(data.corners()[board])
        truth = np.array(
            [
                [float(r[f"cam_{a}"]) for a in "xyz"]
                for r, k in zip(data.rows, board, strict=True)
                if k
            ]
        )
        fx = np.array([float(r["fx"]) for r, k in zip(data.rows, board, strict=True) if k])
        aspect = torch.from_numpy(data.pixel_aspect()[board])
        sources = np.array(data.column("source"))[board]
        H = square_homography(net.undistorted(q, aspect))
        found = {}
        for use in (False, True):
            a = aspect if use else torch.ones_like(aspect)
            with torch.no_grad():
                focal = net.focal_length(net.centred_homography(H, a))
                found[use] = (net.camera_centre(H, a).numpy(), focal.numpy())
        for source in sorted(set(sources[np.abs(aspect.numpy() - 1) > 0.01])):
            m = sources == source
            cells = [f"{source} ({split})", f"{float(aspect[m].mean()):.2f}"]
            for use in (False, True):
                centre, focal = found[use]
                cells.append(
                    f"{np.median(np.abs(centre[m, 2] - truth[m, 2])):.1f} cm, "
                    f"{np.median(focal[m] / fx[m]):.2f} x"
                )
            rows.append(cells)
    return rows


def portrait_table(net: CornerNet) -> list[list[str]]:
    """The val 4:3 board photos turned to portrait, squashed to 160x120 or turned back."""
    splits = read_splits(CORPUS / "splits.toml")
    photos, labels = [], []
    for source in sorted((CORPUS / "boards").iterdir()):
        if splits.get(source.name) != "val":
            continue
        with (source / "labels.csv").open(newline="") as fh:
            for row in csv.DictReader(fh):
                rgb = read_rgb(source / row["file"])
                if abs(rgb.shape[1] * 3 - rgb.shape[0] * 4) > 8 or not row.get("cam_z"):
                    continue
                photos.append(cv2.rotate(rgb, cv2.ROTATE_90_COUNTERCLOCKWISE))
                labels.append(pose_class([float(row[f"cam_{a}"]) for a in "xyz"], Z_SPLIT_CM))
    y = np.array(labels)
    size = SIZES[2]
    squashed = np.stack([cv2.resize(p, size, interpolation=cv2.INTER_AREA) for p in photos])
    turned = np.stack([to_network_input(p, size) for p in photos])
    frames = [NetworkFrame((p.shape[1], p.shape[0]), size) for p in photos]
    squash_aspect = torch.tensor([(size[1] / p.shape[0]) / (size[0] / p.shape[1]) for p in photos])
    variants = {
        "squashed, square pixels": (to_input(squashed), None),
        "squashed, its pixel aspect (0.56)": (to_input(squashed), squash_aspect),
        "turned to landscape (the service)": (
            torch.from_numpy(turned),
            torch.tensor([f.pixel_aspect for f in frames]),
        ),
    }
    rows = []
    for name, (x, aspect) in variants.items():
        with torch.no_grad():
            predicted = net.logits(x, aspect).argmax(1).numpy()
        rows.append([name, str(len(y)), f"{100 * np.mean(predicted == y):.1f}"])
    return rows


def _corner_net(path: Path) -> CornerNet:
    """The corner network of a training checkpoint or an exported ONNX model (eval mode), or
    exit with the reason."""
    try:
        if path.suffix == ".onnx":
            net, _ = corner_net_from_onnx(path)
        else:
            net, _ = load_network(path)
    except ValueError as exc:  # TrainingError, OnnxWeightsError: a one-line reason
        sys.exit(f"error: {exc}")
    if not isinstance(net, CornerNet):
        sys.exit(f"error: {path} is not a corner network")
    return net.eval()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "checkpoint", type=Path, help="a corner training checkpoint (best.pt) or ONNX model"
    )
    parser.add_argument("data", type=Path, help="the folder of the real-s2-b0..3 data sets")
    parser.add_argument("--out", type=Path, default=REPO_ROOT / "docs/camera_model.md")
    args = parser.parse_args()
    sets = [args.data / f"{kind}-s2-b{b}" for kind in ("real", "spec", "tele") for b in range(4)]
    for path in (args.checkpoint, *sets):
        if not path.exists():
            sys.exit(f"error: not found: {path} (run scripts/train_default.sh first)")
    net = _corner_net(args.checkpoint)
    cache = _caches(net, args.data)
    code_range = net.align.k1_range
    net.align.k1_range = (K1_LOWER, code_range[1])
    narrow = _caches(net, args.data)
    net.align.k1_range = code_range
    lines = [
        "# The corner network's camera model, measured on the real val and train sources",
        "",
        written_by(f"python scripts/camera_model_choices.py {args.checkpoint} {args.data}")
        + " The constants are in `service/core/pose.py` (`FOCAL_PRIOR`, `FOCAL_BOUNDS`; a "
        "profile may state its own prior, `focal_prior`), `train/network/corners.py` "
        "(`FOCAL_PRIOR_WEIGHT`, `BARREL_LIMIT`, "
        f"`RADIAL_PRIOR` = {corner_net.RADIAL_PRIOR:g}: the prior of the k1 the corner "
        "alignment fits per image, `train/network/align.py`) and `service/core/preprocess.py` "
        "(`NetworkFrame`); docs/decisions.md says why. The rows with a fixed k1 pose every "
        "image with it (the corners aligned as the code does).",
        "",
        "## Class accuracy (%) at blur 0 / 1 / 2 / 3",
        "",
        *table(["camera model", *SPLIT_HEADER], accuracy_table(net, cache)),
        "",
        "## The labelled corners of the cameras that are not 4:3 (blur 0)",
        "",
        "Median |camera z - truth| and median self-calibrated focal length / calibrated fx.",
        "",
        *table(
            ["camera (split)", "pixel aspect", "square pixels", "pixel aspect"],
            labelled_corner_table(net, args.data),
        ),
        "",
        "## The focal-length prior (pixel aspect, the code's k1): class accuracy (%) at blur "
        "0 / 1 / 2 / 3",
        "",
        f"The code's: {corner_net.FOCAL_PRIOR:g} x SPEC, weight {DEFAULT_PRIOR_WEIGHT:g}.",
        "",
        "The renders of the SPEC's own camera (`chessboard-spec`, focal length 1 x) want a "
        "longer prior than the real cameras: docs/decisions.md says what was chosen and why.",
        "",
        *table(["focal prior", *SPLIT_HEADER], focal_prior_table(net, cache)),
        "",
        "## The bounds of the focal-length estimate (the code's prior and weight): class "
        "accuracy (%) at blur 0 / 1 / 2 / 3",
        "",
        f"The code's: {FOCAL_BOUNDS[0]:g}-{FOCAL_BOUNDS[1]:g} x SPEC.",
        "",
        *table(["focal-length bounds", *SPLIT_HEADER], focal_bounds_table(net, cache)),
        "",
        "## The focal-length prior shortened by a strong barrel distortion: class accuracy "
        "(%) at blur 0 / 1 / 2 / 3",
        "",
        f"The code's: limit {corner_net.BARREL_LIMIT:g}, k1 range "
        f"{code_range[0]:g}..{code_range[1]:g}. A k1 fitted beyond the limit (in the prior "
        "camera's coordinates) shortens the prior focal length f0 to f0 sqrt(limit / k1): "
        "a lens's own barrel rarely goes further (`BARREL_LIMIT`).",
        "",
        *table(["k1 range, barrel limit", *SPLIT_HEADER], barrel_limit_table(net, cache, narrow)),
        "",
        *_limit_sections(net, cache),
    ]
    args.out.write_text("\n".join(lines))
    print(f"wrote {args.out}")


def _limit_sections(net: CornerNet, cache: dict[tuple[str, int], Cached]) -> list[str]:
    """The page's last sections: the principal point, what limits the answer, portraits."""
    return [
        "## The principal point (the code's focal prior and k1): class accuracy (%) at blur "
        "0 / 1 / 2 / 3",
        "",
        *table(["principal point", *SPLIT_HEADER], principal_point_table(net, cache)),
        "",
        "## What limits the answer: class accuracy (%) at blur 0 / 1 / 2 / 3",
        "",
        "The network's corners, the labelled ones or those of OpenCV's chessboard detector "
        "as `planar-pose compare` runs it (the 160x120 image enlarged 4x; the network's "
        "corners where it finds no board); the self-calibrated camera (the code's model) or "
        "each photo's calibrated one (labels.csv); presence from the network in all. The "
        "detector's rows show whether its lead in docs/comparison.md, where it is given each "
        "photo's calibrated camera, comes from its corners or from that camera.",
        "",
        *table(["split", "corners, camera", "accuracy"], limits_table(net, cache)),
        "",
        "## Portraits: the val 4:3 board photos turned a quarter counter-clockwise",
        "",
        *table(["input", "photos", "accuracy (%)"], portrait_table(net)),
        "",
    ]


if __name__ == "__main__":
    main()
