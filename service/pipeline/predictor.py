"""Bytes of one or many images -> per-image answers, the HTTP-free core of `/v1/predict`.

Every image of a call goes through ONE batched onnxruntime run (whole mode: one input per
image, then one more for the zoom pass's crops where it applies, `service.pipeline.zoom`; sliding
mode: all windows of all images). Thread-safe: the session is shared.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from service.core.calibration import fit_camera
from service.core.cells import RegionGrid
from service.core.frame import object_corners
from service.core.preprocess import (
    DecodedImage,
    ImageDecodeError,
    NetworkFrame,
    camera_pixels,
    load_grey,
    load_image,
    to_network_input,
)
from service.core.refine import (
    GOOD_SCORE,
    MAX_EXTENT_PX,
    REFINED_NOISE_PX,
    CameraLens,
    Features,
    FeatureSearch,
    Lens,
    RadialLens,
    Refinement,
    Texture,
    extent,
    image_centre,
    refine_corners,
)
from service.core.regions import pose_probabilities, region_of_class
from service.pipeline.exif import exif_focal
from service.pipeline.focal import KnownFocal
from service.pipeline.job import ImageInput, Job, Options, Upload, admit
from service.pipeline.model import Answer, PoseModel
from service.pipeline.posing import cell_of, focal_of, pose_of
from service.pipeline.proposals import propose_boxes
from service.pipeline.results import (
    Box,
    Detection,
    ImageResult,
    Mode,
    RefinementReport,
    Region,
)
from service.pipeline.results import Lens as LensName
from service.pipeline.sliding import (
    BoxGenerator,
    SlidingWindows,
    best_window,
    to_full_resolution,
    window_batch,
    working_copy,
    working_min_size,
)
from service.pipeline.zoom import detail_decode_size, detail_of, zoomed
from service.settings import Settings

_LIBC = ctypes.CDLL(ctypes.util.find_library("c") or None)


def give_back_memory() -> None:
    """Hand the free memory of the C heap back to the OS (glibc's `malloc_trim`; nothing
    where the C library has no such call): decoding a large image leaves it held."""
    trim = getattr(_LIBC, "malloc_trim", None)
    if trim is not None:
        trim(0)


#: Decoded pixels of a request beyond which the process hands freed memory back to the OS.
TRIM_ABOVE_PIXELS = 8_000_000


@dataclass(frozen=True)
class _JointFocal(KnownFocal):
    """A same-camera request's fitted focal length and the range (lo, hi) px its photos
    allow, px of images of its `size`."""

    interval: tuple[float, float] | None = None


def image_corners(
    answer: Answer, frames: Sequence[NetworkFrame]
) -> tuple[np.ndarray, np.ndarray] | None:
    """The answer's corners [N, 4, 2] in px of the uploaded images, as seen and as a pinhole
    camera would see them (the graph's `undistorted`; the same as seen for a graph without
    it), or None for a graph without corners."""
    if answer.corners is None:
        return None
    seen = np.stack([f.to_image(q) for f, q in zip(frames, answer.corners, strict=True)])
    if answer.undistorted is None:
        return seen, seen
    flat = np.stack([f.to_image(q) for f, q in zip(frames, answer.undistorted, strict=True)])
    return seen, flat


#: The refinement runs on photos with at least this many times the network input's pixels
#: along their longer side: below, the network read every pixel there is (chessboard renders
#: at 160x120: 85 % right with the network's corners, 79 % refined; docs/decisions.md).
MIN_PHOTO_SCALE = 2.0
#: A tracked frame's alignment must correlate this well, else the network answers it.
TRACK_SCORE = 0.7
#: A stream's network frame whose object lies within this many px of the track's corners
#: (each corner, the photo's pixels) keeps the track (`Predictor.confirm`).
TRACK_AGREE_PX = 1.0
#: A second opinion where the network calls the object absent: an image it gives at least
#: this P(present) has its corners refined at the photo's resolution all the same, and the
#: object is present where the texture then aligns with a correlation of `PRESENT_SCORE` or
#: more (that correlation its P(present)). ChArUco val frames (camera 0, 1280x720), the
#: zero-shot model: 34 of 46 frames called absent at P(present) 0.14-0.47, 30 of them aligned
#: at 0.81-0.96; the 22 shipped backgrounds of 320 px or more: no alignment held on any
#: (docs/decisions.md).
RESCUE_FROM_P, PRESENT_SCORE = 0.1, 0.8
#: The second opinion of a zero-shot model from this P(present): its presence is set to call
#: 97 % of absent renders absent (train/network/zeroshot.py), so its "absent" is the less sure.
#: Its ChArUco val frames at 1280x720: six more found at P(present) 0.06-0.09 (78 -> 93 %,
#: camera registered 65.2 -> 73.9 % right; 0.02: no more). For every model it cost 2.7x on a
#: photo without the object the book model hesitates over (docs/benchmarks.md), for no val
#: frame of the shipped models.
ZERO_SHOT_RESCUE_FROM_P = 0.05


@dataclass(frozen=True)
class Track:
    """Where a stream's last answered frame showed the object: its corners [4, 2] px as
    seen, the radial lens fitted there (kappa px^-2, None: none), P(present)."""

    corners: np.ndarray
    kappa: float | None
    present: float


@dataclass(frozen=True)
class ObjectView:
    """Where an image shows the object: its corners [4, 2] px of the uploaded image as seen,
    as a pinhole camera sees them with `lens` undone, the refinement that made them (None:
    not run), the radial lens it fitted (kappa px^-2 of the uploaded image about its
    centre, `service.core.refine.RadialLens`; None: none fitted) and the texture's features
    it followed (px of the uploaded image; None: none)."""

    seen: np.ndarray
    pinhole: np.ndarray
    lens: LensName
    refinement: Refinement | None = None
    kappa: float | None = None
    features: Features | None = None
    present: float | None = None  # P(present) from the alignment where the network missed it


def _camera_lens(known: KnownFocal | None, size: tuple[int, int]) -> CameraLens | None:
    """A registered camera's whole lens for an image of `size` (W, H), or None where none is
    known or it was learned from photos (each image fits its own: docs/decisions.md)."""
    camera = None if known is None else known.camera(size)
    if known is None or camera is None or camera.dist is None or known.lens_learned:
        return None
    return CameraLens(camera)


def _reduction(corners: np.ndarray) -> int:
    """How far a photo may be decoded reduced for the refinement: its object's extent
    (`corners` [4, 2] px) still `MAX_EXTENT_PX` or more."""
    return max(1, int(extent(corners) / MAX_EXTENT_PX))


def _refinement_report(ref: Refinement) -> RefinementReport:
    def rounded(v: float) -> float | None:
        return round(v, 4) if math.isfinite(v) else None

    return RefinementReport(
        score=rounded(ref.score) if ref.refined else None,
        start_score=rounded(ref.start_score),
        half_turned=ref.turned,
        reason=ref.reason,
        elapsed_ms=round(ref.elapsed_ms, 2),
    )


@dataclass(frozen=True)
class Prediction:
    results: list[ImageResult]
    inference_s: float  # the batched onnxruntime call, seconds
    #: per image, where the object was found: its corners [4, 2] px of the uploaded image as
    #: a pinhole camera would see them (the lens undone), else None
    pinhole: list[np.ndarray | None]
    #: per image, the radial lens its refinement fitted (kappa px^-2 about the image's
    #: centre, `ObjectView.kappa`), else None
    kappas: list[float | None]
    #: per image, the texture's features its refinement followed (`ObjectView.features`)
    features: list[Features | None]


def _box(box: tuple[int, int, int, int], scale: tuple[float, float], size: tuple[int, int]) -> Box:
    x, y, w, h = to_full_resolution(box, scale, size)
    return Box(x=x, y=y, w=w, h=h)


def _result(
    filename: str | None,
    class_id: int,
    probs: np.ndarray,
    elapsed_s: float,
    size: tuple[int, int],
) -> ImageResult:
    return ImageResult(
        filename=filename,
        image_size=list(size),
        class_id=class_id,
        region=Region(**region_of_class(class_id)),
        probabilities=probs.tolist(),
        confidence=float(probs[class_id]),
        box=None,
        elapsed_ms=1000.0 * elapsed_s,
    )


class Predictor:
    """Decode, preprocess and classify images with one model, in whole or sliding mode."""

    def __init__(self, model: PoseModel, settings: Settings, boxes: BoxGenerator | None = None):
        self.model = model
        self.settings = settings
        self.boxes = boxes or SlidingWindows.for_network(
            model.input_size,
            settings.sliding_scales,
            settings.sliding_stride,
            settings.sliding_max_windows,
        )

    def _load(self, upload: Upload, min_size: tuple[int, int]) -> DecodedImage:
        try:  # its size was checked from its header (`admit`)
            return load_image(upload.data, min_size=min_size, header=upload.header)
        except ImageDecodeError as exc:
            raise type(exc)(f"{upload.name}: {exc}") from None

    def min_size(self, mode: Mode) -> tuple[int, int]:
        """The least size (W, H) `mode` decodes an image at (a large JPEG is decoded reduced
        down to it): whole mode the zoom pass's detail, else the working copy's."""
        size = self.model.input_size
        if mode == "sliding":
            return working_min_size(size, self.settings.sliding_resolution)
        if mode == "proposals":
            return working_min_size(size, self.settings.proposals_resolution)
        return detail_decode_size(size)

    def admit(self, images: Sequence[ImageInput], options: Options) -> Job:
        """The request's images read from their headers, once, and refused by size before
        any is decoded (`job.admit`: ImageDecodeError, ImageTooLargeError, PixelBudgetError,
        each naming the image)."""
        cfg = self.settings
        min_size = self.min_size(options.mode)
        return admit(images, options, min_size, cfg.max_pixels, cfg.max_request_pixels)

    def _infer(self, batch: np.ndarray) -> tuple[np.ndarray, float]:
        """Batch [N, 3, H, W] -> probabilities [N, 9], seconds."""
        t0 = time.perf_counter()
        probs = self.model.predict(batch)
        return probs, time.perf_counter() - t0

    def _proposals(self, image: np.ndarray) -> np.ndarray:
        """Object-proposal boxes (SPEC 9, objectness) of the network's aspect in `image`."""
        w, h = self.model.input_size
        return propose_boxes(image, w / h, self.settings.proposals_max)

    def focal_problem(
        self, mode: Mode, focal: KnownFocal | None, same_camera: bool = False
    ) -> str | None:
        """Why the known focal length `focal` (or a `same_camera` fit) cannot be used with
        `mode` and this model, or None when it can (or neither is asked for); its range was
        checked where it was made (`service.pipeline.focal`)."""
        if focal is None and not same_camera:
            return None
        what = (
            "same_camera"
            if focal is None
            else {"query": "fx", "camera": "camera"}.get(focal.source, "fx")
        )
        if focal is not None and same_camera:
            return f"same_camera: the focal length is known already ({what}); give one of them"
        if mode != "whole":
            return f"{what}: applies to mode=whole only, not mode={mode}"
        if not self.model.takes_focal:
            return f"{what}: model {self.model.name} does not take a focal length"
        return None

    def options(
        self,
        mode: Mode,
        focal: KnownFocal | None = None,
        same_camera: bool = False,
        grid: RegionGrid | None = None,
    ) -> Options:
        """A request's options, checked once: ValueError for a `focal` / `same_camera` that
        `focal_problem` refuses.

        whole: the image as one input; sliding: the window grid; proposals: object proposals.
        `focal`: the camera's focal length (px of the images, scaled to each one's size), which
        the class and the pose then use instead of estimating it; `same_camera`: the images
        are one camera's, whose focal length is fitted to all their corners (whole mode,
        corner models). `grid`: the finer regions each pose's `cell` is named in.
        """
        problem = self.focal_problem(mode, focal, same_camera)
        if problem is not None:
            raise ValueError(problem)
        return Options(mode, focal, same_camera, grid)

    def predict(
        self,
        images: Sequence[ImageInput],
        mode: Mode,
        focal: KnownFocal | None = None,
        same_camera: bool = False,
        grid: RegionGrid | None = None,
    ) -> Prediction:
        """Answer every image (`options`, `admit`, then `run`); raises ValueError,
        ImageDecodeError or ImageTooLargeError as they do."""
        return self.run(self.admit(images, self.options(mode, focal, same_camera, grid)))

    def run(self, job: Job) -> Prediction:
        """Answer every image of an admitted request in one batched network call;
        ImageDecodeError naming an image that does not decode."""
        mode = job.options.mode
        try:
            if mode == "sliding":
                return self._detect(job.uploads, self.boxes, self.settings.sliding_resolution)
            if mode == "proposals":
                res = self.settings.proposals_resolution
                return self._detect(job.uploads, self._proposals, res)
            return self._whole(job.uploads, job.options)
        finally:
            if job.pixels > TRIM_ABOVE_PIXELS:
                give_back_memory()

    def _whole(self, images: list[Upload], options: Options) -> Prediction:
        size, inputs, prep, frames, known = self.model.input_size, [], [], [], []
        zoom = self.settings.zoom and self.model.zooms
        detail: list[np.ndarray | None] = []  # the zoom pass's frames at 2x the input size
        # decoded the same with the pass off, so that the network input is made the same way
        decode = detail_decode_size(size)
        focal, grid = options.focal, options.grid
        for image in images:
            t0 = time.perf_counter()
            decoded = self._load(image, decode)
            inputs.append(to_network_input(decoded.rgb, size))
            if zoom:
                detail.append(detail_of(decoded.rgb, size))
            frames.append(NetworkFrame((decoded.width, decoded.height), size))
            known.append(focal or self._exif_focal(image.data, (decoded.width, decoded.height)))
            prep.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        answer = self._run(np.stack(inputs), frames, known, detail if zoom else None)
        infer_s = time.perf_counter() - t0
        share = infer_s / len(images)
        views = self._views(images, answer, frames, known, prep)
        joint = self._joint_focal(views, frames) if options.same_camera else None
        if joint is not None:
            known = [joint] * len(images)
        results: list[ImageResult] = []
        for i, (image, p, k, view) in enumerate(
            zip(images, answer.probabilities, known, views, strict=True)
        ):
            image_size = frames[i].image_size
            result = _result(image.filename, int(p.argmax()), p, prep[i] + share, image_size)
            if view is not None:
                self._add_view(result, view, image_size, k, joint, grid)
            if k is not None:
                result.fx = k.camera(image_size).fx
                result.fx_source = k.source
            results.append(result)
        found = [v if r.class_id else None for v, r in zip(views, results, strict=True)]
        return Prediction(
            results,
            infer_s,
            [None if v is None else v.pinhole for v in found],
            [None if v is None else v.kappa for v in found],
            [None if v is None else v.features for v in found],
        )

    def _run(
        self,
        batch: np.ndarray,
        frames: list[NetworkFrame],
        known: Sequence[KnownFocal | None],
        detail: list[np.ndarray | None] | None,
    ) -> Answer:
        """The network's answer for the inputs [N, 3, H, W] of `frames`, with the focal length
        of each where it is known, through the zoom pass where `detail` is given."""
        aspect = np.array([f.pixel_aspect for f in frames], dtype=np.float32)
        focal = None  # 0 for an image: unknown, estimated (`PoseModel.run`)
        if any(k is not None for k in known):
            focal = np.array(
                [
                    0.0 if k is None else f.input_focal(k.camera(f.image_size).fx)
                    for f, k in zip(frames, known, strict=True)
                ],
                np.float32,
            )
        if detail is not None:
            cfg = self.settings
            # A zero-shot model searches no tile of a photo without more pixels than the
            # network reads (no `detail`): its presence threshold is measured on whole frames
            # (train/network/zeroshot.py), and a look at that enlarged tile lets more absent
            # images pass it, for no detail gained (docs/decisions.md).
            trained = self.model.training != "zero-shot"
            search = [cfg.zoom_search and (trained or d is not None) for d in detail]
            return zoomed(self.model, batch, aspect, search, focal, detail, cfg.zoom_search_tiles)
        return self.model.run(batch, aspect, focal=focal)

    def _views(
        self,
        images: list[Upload],
        answer: Answer,
        frames: list[NetworkFrame],
        known: Sequence[KnownFocal | None],
        prep: list[float],
    ) -> list[ObjectView | None]:
        """Each image's `ObjectView` where the network found the object (None elsewhere, and
        for graphs without corners), refined where the model carries its texture, the
        settings ask for it and the photo has more pixels than the network read
        (`MIN_PHOTO_SCALE`; the refinement's time is added to the image's `prep`; the
        texture's features searched near the network's corners where a trained network found
        it, else in the whole photo); and where the network missed it but the texture aligns
        there (`RESCUE_FROM_P`, a zero-shot model's `ZERO_SHOT_RESCUE_FROM_P`;
        `PRESENT_SCORE`)."""
        corners = image_corners(answer, frames)
        if corners is None:
            return [None] * len(images)
        views: list[ObjectView | None] = []
        texture = self.model.texture if self.settings.refine else None
        zero_shot = self.model.training == "zero-shot"
        rescue_from = ZERO_SHOT_RESCUE_FROM_P if zero_shot else RESCUE_FROM_P
        for i, p in enumerate(answer.probabilities):
            seen, size = corners[0][i], frames[i].image_size
            large = max(size) >= MIN_PHOTO_SCALE * max(self.model.input_size)
            aligns = texture if large else None  # the texture, where the photo has more pixels
            missed = p.argmax() == 0  # a second opinion where it may be there (`RESCUE_FROM_P`)
            if missed and (aligns is None or 1.0 - p[0] < rescue_from):
                views.append(None)
                continue
            lens: Lens | None = _camera_lens(known[i], size)
            kind: LensName = "none" if lens is None else "camera"
            if lens is None and answer.undistorted is not None:  # fitted again by refinement
                lens, kind = RadialLens.fitted(seen, corners[1][i], image_centre(size)), "network"
            pinhole = seen if lens is None else lens.undistort(seen)
            view = ObjectView(seen, pinhole, kind)
            if aligns is not None:
                t0 = time.perf_counter()
                # the features near the corners of a trained network that found the object;
                # elsewhere its corners mark no place (docs/decisions.md)
                near = not (missed or zero_shot)
                view = self._refined(images[i], view, aligns, lens, "near" if near else "photo")
                prep[i] += time.perf_counter() - t0
            ref = view.refinement
            if not missed:
                views.append(view)
            elif ref is not None and ref.refined and ref.score >= PRESENT_SCORE:
                views.append(replace(view, present=ref.score))
            else:
                views.append(None)
        return views

    def _refined(
        self,
        image: Upload,
        view: ObjectView,
        texture: Texture,
        lens: Lens | None,
        features: FeatureSearch,
    ) -> ObjectView:
        """`view` with its corners refined at the photo's own resolution (`refine_corners`,
        the texture's features searched where `features` says), the photo decoded reduced as
        far as the object keeps `MAX_EXTENT_PX` of extent."""
        grey, f, _ = load_grey(image.data, _reduction(view.pinhole), image.header)
        fit = view.lens != "camera"  # a lens not known is fitted with the alignment
        ref = refine_corners(
            grey,
            (view.seen + 0.5) / f - 0.5,
            texture,
            None if lens is None else lens.reduced(f),
            self.settings.refine_budget_ms,
            fit_lens=fit,
            features=features,
        )
        if not ref.refined:
            return replace(view, refinement=ref)
        seen, pinhole = ((q + 0.5) * f - 0.5 for q in (ref.corners, ref.pinhole))
        kappa = ref.lens.kappa / f**2 if isinstance(ref.lens, RadialLens) else None
        points = ref.features
        if points is not None:  # px of the uploaded image
            points = replace(points, seen=(points.seen + 0.5) * f - 0.5)
        return ObjectView(seen, pinhole, "fitted" if fit else view.lens, ref, kappa, points)

    def _joint_focal(
        self, views: list[ObjectView | None], frames: list[NetworkFrame]
    ) -> _JointFocal | None:
        """One camera fitted to the pinhole corners [4, 2] px of every image the object was
        found in (`fit_camera`, in px of the first one's size turned to landscape,
        `camera_pixels`), or None with fewer than 2."""
        size_cm = self.model.object_size_cm
        found = [(v, f.image_size) for v, f in zip(views, frames, strict=True) if v is not None]
        if size_cm is None or len(found) < 2:
            return None
        first = found[0][1]
        size = (max(first), min(first))  # the camera's landscape frame: portraits turned
        corners = [camera_pixels(v.pinhole, image_size, size) for v, image_size in found]
        kappas = [
            None if v.kappa is None else v.kappa * (max(image_size) / max(size)) ** 2
            for v, image_size in found
        ]
        features = [
            None if v.features is None
            else replace(v.features, seen=camera_pixels(v.features.seen, image_size, size))
            for v, image_size in found
        ]  # fmt: skip
        fit = fit_camera(corners, kappas, object_corners(*size_cm, z=True), size, features)
        return _JointFocal(fit.fx, "estimated", size, interval=fit.fx_range)

    def _add_view(
        self,
        result: ImageResult,
        view: ObjectView,
        size: tuple[int, int],
        known: KnownFocal | None,
        joint: _JointFocal | None,
        grid: RegionGrid | None,
    ) -> None:
        """The corners, `pose` (and with `grid` the `cell`) of an image whose object was found,
        and its class from that pose: the probabilities of the pose's centre
        (`pose_probabilities`) with the network's P(present) (the alignment's where the network
        missed it, `ObjectView.present`), so that the class is the pose's region. Without a
        pose (no object size, degenerate corners) the network's class stands."""
        ref = view.refinement
        result.corners = view.seen.tolist()
        result.corners_source = "refined" if ref is not None and ref.refined else "network"
        if ref is not None:
            result.refinement = _refinement_report(ref)
        size_cm = self.model.object_size_cm
        if size_cm is None:
            return
        sharp = ref is not None and ref.refined and ref.score >= GOOD_SCORE
        noise = REFINED_NOISE_PX if sharp else None
        focal = focal_of(view.pinhole, size, size_cm, known, self.model.focal_prior, noise)
        if joint is not None and joint.interval is not None:
            s = joint.scale(size)
            focal = replace(focal, interval=(joint.interval[0] * s, joint.interval[1] * s))
        try:
            pose = pose_of(view.pinhole, size_cm, focal, view.lens)
            cell = None if grid is None else cell_of(grid, view.pinhole, size_cm, focal)
        except (ValueError, np.linalg.LinAlgError):  # corners that give no pose (degenerate)
            return
        present = 1.0 - float(result.probabilities[0]) if view.present is None else view.present
        probs = pose_probabilities(pose.camera_cm, self.model.z_split_cm, present)
        class_id = int(probs.argmax())
        result.probabilities, result.confidence = probs.tolist(), float(probs[class_id])
        result.class_id, result.region = class_id, Region(**region_of_class(class_id))
        if class_id != 0:
            result.pose, result.cell = pose, cell
        else:  # the pose's region is less likely than the object's absence
            result.corners = result.corners_source = result.refinement = None

    def follow(self, job: Job, last: Track) -> Prediction | None:
        """The one frame of `job`, of a stream whose object the frame before showed at `last`:
        its corners refined from there (no network, no feature search, the last frame's
        lens), or None where the model carries no texture, refinement is off, the frame is small
        (`MIN_PHOTO_SCALE`), or the alignment does not hold at `TRACK_SCORE` (then the
        network answers the frame, `run`); ImageDecodeError for a frame that does not decode."""
        texture, size_cm = self.model.texture, self.model.object_size_cm
        if texture is None or size_cm is None or not self.settings.refine:
            return None
        t0 = time.perf_counter()
        image, focal, grid = job.uploads[0], job.options.focal, job.options.grid
        grey, f, size = load_grey(image.data, _reduction(last.corners), image.header)
        if max(size) < MIN_PHOTO_SCALE * max(self.model.input_size):
            return None
        lens: Lens | None = _camera_lens(focal, size)
        kind: LensName = "fitted" if lens is None else "camera"
        if lens is None:
            lens = RadialLens(image_centre(size), last.kappa or 0.0)
        ref = refine_corners(
            grey,
            (last.corners + 0.5) / f - 0.5,
            texture,
            lens.reduced(f),
            self.settings.refine_budget_ms,
            features="off",
        )
        if not ref.refined or ref.score < TRACK_SCORE:
            return None
        seen, pinhole = ((q + 0.5) * f - 0.5 for q in (ref.corners, ref.pinhole))
        kappa = last.kappa if kind == "fitted" else None
        view = ObjectView(seen, pinhole, kind, ref, kappa)
        probs = np.array([1 - last.present] + [last.present / 8] * 8)
        result = _result(None, 1, probs, 0.0, size)
        self._add_view(result, view, size, focal, None, grid)
        result.tracked = True
        if focal is not None:
            result.fx, result.fx_source = focal.camera(size).fx, focal.source
        result.elapsed_ms = 1000.0 * (time.perf_counter() - t0)
        found = result.class_id != 0
        return Prediction(
            [result], 0.0, [pinhole if found else None], [kappa if found else None], [None]
        )

    def stream_frame(self, job: Job, last: Track | None, since: int) -> tuple[Prediction, int]:
        """One frame of a stream, whole mode: `last` where the frame before showed the object
        (None: it did not), `since` frames tracked since the network last looked -> the answer
        and that count after it. Tracked from `last` (`follow`) until the network's turn, every
        `Settings.stream_track_every` frames (below 2: no tracking), where the track stands if
        the network agrees with it (`confirm`); the network's answer where the track is lost."""
        every = self.settings.stream_track_every
        due = since + 1 >= every
        if every < 2:
            last = None
        if last is not None and not due:
            tracked = self.follow(job, last)
            if tracked is not None:
                return tracked, since + 1
        network = self.run(job)
        if network.results[0].corners is not None:
            network.results[0].tracked = False
        if last is not None and due:
            return self.confirm(job, last, network), 0
        return network, 0

    def confirm(self, job: Job, last: Track, network: Prediction) -> Prediction:
        """A stream's frame that the network answered (`network`, `run`'s) while the frame
        before showed the object at `last`: that frame tracked from there (`follow`) where
        the network found the object within `TRACK_AGREE_PX` of the track, else the network's
        answer (the track drifted or was lost). The network's own alignment of a still object
        is a new draw of the photo's noise; the track's stays put (ChArUco still sequences,
        `benchmarks/bench_refine.py`)."""
        result = network.results[0]
        if result.corners is None or not result.class_id:
            return network
        if np.abs(np.array(result.corners) - last.corners).max() > TRACK_AGREE_PX:
            return network
        return self.follow(job, last) or network

    def _exif_focal(self, data: bytes, size: tuple[int, int]) -> KnownFocal | None:
        """The focal length of the photo's EXIF (`exif_focal`), px of its `size` (W, H), or
        None (unknown, or EXIF focal lengths off)."""
        if self.settings.exif_focal and self.model.takes_focal:
            exif_fx = exif_focal(data, size)
            if exif_fx is not None:
                return KnownFocal(exif_fx, "exif", size)
        return None

    def _detect(
        self, images: list[Upload], boxes_of: BoxGenerator, resolution: float
    ) -> Prediction:
        """Classify the boxes `boxes_of` finds in a working copy of each image (one batched
        call for all), keep the best window per image (NMS, class 0 windows dropped)."""
        size, cfg = self.model.input_size, self.settings
        min_size = working_min_size(size, resolution)
        staged, batches, prep = [], [], []
        for image in images:
            t0 = time.perf_counter()
            decoded = self._load(image, min_size)
            work, scale = working_copy(decoded, size, resolution)
            boxes = boxes_of(work)
            batches.append(window_batch(work, boxes, size))
            staged.append((boxes, scale, (decoded.width, decoded.height)))
            prep.append(time.perf_counter() - t0)
        probs, infer_s = self._infer(np.concatenate(batches))
        total, start, results = len(probs), 0, []
        for image, (boxes, scale, full), t in zip(images, staged, prep, strict=True):
            answer = best_window(boxes, probs[start : start + len(boxes)], cfg.sliding_nms_iou)
            result = _result(
                image.filename,
                answer.class_id,
                answer.probabilities,
                t + infer_s * len(boxes) / total,
                full,
            )
            if answer.box is not None:
                result.box = _box(answer.box, scale, full)
            result.detections = [
                Detection(class_id=c, confidence=s, box=_box(b, scale, full))
                for b, c, s in answer.detections
            ]
            results.append(result)
            start += len(boxes)
        n = len(results)
        return Prediction(results, infer_s, [None] * n, [None] * n, [None] * n)
