"""Bytes of one or many images -> per-image answers, the HTTP-free core of `/v1/predict`.

Every image of a call goes through ONE batched onnxruntime run (whole mode: one input per
image, then one more for the zoom pass's tiles where it applies, `service.zoom`; sliding
mode: all windows of all images). Thread-safe: the session is shared.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from service.core.preprocess import (
    DecodedImage,
    ImageDecodeError,
    ImageTooLargeError,
    NetworkFrame,
    decoded_pixels,
    image_header,
    load_image,
    to_network_input,
)
from service.core.regions import region_of_class
from service.exif import exif_focal
from service.model import PoseModel
from service.proposals import propose_boxes
from service.schemas import Box, Detection, FocalSource, ImageResult, Mode, RegionOut
from service.settings import Settings
from service.sliding import (
    BoxGenerator,
    SlidingWindows,
    best_window,
    to_full_resolution,
    window_batch,
    working_copy,
    working_min_size,
)
from service.zoom import detail_decode_size, detail_of, zoomed

_LIBC = ctypes.CDLL(ctypes.util.find_library("c") or None)


def give_back_memory() -> None:
    """Hand the free memory of the C heap back to the OS (glibc's `malloc_trim`; nothing
    where the C library has no such call): decoding a large image leaves it held."""
    trim = getattr(_LIBC, "malloc_trim", None)
    if trim is not None:
        trim(0)


#: (filename or None, encoded image bytes)
ImageInput = tuple[str | None, bytes]


#: The range of a camera's focal length `fx` a request may give, in pixels of its images: a
#: fisheye of 1 px per radian on a tiny image to a long lens on a large sensor (a 600 mm
#: lens on a 24 mm wide 8000 px sensor is 200,000 px: 1e5 is f = 300 mm there). Outside,
#: float32 would turn it to 0 (unknown) or inf.
FX_MIN_PX, FX_MAX_PX = 1.0, 100_000.0
#: Decoded pixels of a request beyond which the process hands freed memory back to the OS.
TRIM_ABOVE_PIXELS = 8_000_000


class PixelBudgetError(ImageTooLargeError):
    """The images of one request would decode to more pixels than its budget
    (`Settings.max_request_pixels`): refused from their headers, before any is decoded."""


def too_large_code(exc: ImageTooLargeError) -> str:
    """The error code of a refusal by size: the request's budget or one image's limit."""
    return "pixel_budget_exceeded" if isinstance(exc, PixelBudgetError) else "image_too_large"


def _name(index: int, image: ImageInput) -> str:
    return f"image {index + 1}" + (f" ({image[0]})" if image[0] else "")


@dataclass(frozen=True)
class Prediction:
    results: list[ImageResult]
    inference_s: float  # the batched onnxruntime call, seconds


def _box(box: tuple[int, int, int, int], scale: tuple[float, float], size: tuple[int, int]) -> Box:
    x, y, w, h = to_full_resolution(box, scale, size)
    return Box(x=x, y=y, w=w, h=h)


def _result(
    filename: str | None, class_id: int, probs: np.ndarray, elapsed_s: float
) -> ImageResult:
    return ImageResult(
        filename=filename,
        class_id=class_id,
        region=RegionOut(**region_of_class(class_id)),
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

    def _load(self, index: int, image: ImageInput, min_size: tuple[int, int]) -> DecodedImage:
        try:
            return load_image(image[1], max_pixels=self.settings.max_pixels, min_size=min_size)
        except ImageDecodeError as exc:
            raise type(exc)(f"{_name(index, image)}: {exc}") from None

    def min_size(self, mode: Mode) -> tuple[int, int]:
        """The least size (W, H) `mode` decodes an image at (a large JPEG is decoded reduced
        down to it): whole mode the zoom pass's detail, else the working copy's."""
        size = self.model.input_size
        if mode == "sliding":
            return working_min_size(size, self.settings.sliding_resolution)
        if mode == "proposals":
            return working_min_size(size, self.settings.proposals_resolution)
        return detail_decode_size(size)

    def check_pixels(self, images: Sequence[ImageInput], mode: Mode) -> int:
        """The pixels the images of one request decode to in `mode`, read from their headers;
        ImageDecodeError (naming the image) for a header that is not an image's,
        ImageTooLargeError for an image above `max_pixels`, PixelBudgetError when all of
        them are above `max_request_pixels`."""
        cfg, min_size, total, largest = self.settings, self.min_size(mode), 0, (0, "")
        for i, image in enumerate(images):
            try:
                header = image_header(image[1])
            except ImageDecodeError as exc:
                raise ImageDecodeError(f"{_name(i, image)}: {exc}") from None
            stored = header.width * header.height
            if stored > cfg.max_pixels:
                raise ImageTooLargeError(
                    f"{_name(i, image)}: image is {header.width}x{header.height} = {stored} "
                    f"pixels, more than the limit of {cfg.max_pixels}"
                )
            pixels = decoded_pixels(header, min_size)
            total += pixels
            largest = max(largest, (pixels, f"{header.width}x{header.height}"))
        if total > cfg.max_request_pixels:
            raise PixelBudgetError(
                f"{len(images)} image(s), the largest {largest[1]}, decode to {total} pixels, "
                f"more than the budget of {cfg.max_request_pixels} pixels per request"
            )
        return total

    def _infer(self, batch: np.ndarray) -> tuple[np.ndarray, float]:
        """Batch [N, 3, H, W] -> probabilities [N, 9], seconds."""
        t0 = time.perf_counter()
        probs = self.model.predict(batch)
        return probs, time.perf_counter() - t0

    def _proposals(self, image: np.ndarray) -> np.ndarray:
        """Object-proposal boxes (SPEC 9, objectness) of the network's aspect in `image`."""
        w, h = self.model.input_size
        return propose_boxes(image, w / h, self.settings.proposals_max)

    def focal_problem(self, mode: Mode, fx: float | None) -> str | None:
        """Why the camera's focal length `fx` (px of the uploaded images) cannot be used
        with `mode` and this model, or None when it can (or is not given)."""
        if fx is None:
            return None
        if not (math.isfinite(fx) and FX_MIN_PX <= fx <= FX_MAX_PX):
            return f"fx: must be {FX_MIN_PX:g} to {FX_MAX_PX:g} pixels, got {fx}"
        if mode != "whole":
            return f"fx: applies to mode=whole only, not mode={mode}"
        if not self.model.takes_focal:
            return f"fx: model {self.model.name} does not take a focal length"
        return None

    def predict(
        self, images: Sequence[ImageInput], mode: Mode, fx: float | None = None
    ) -> Prediction:
        """Answer every image; raises ImageDecodeError/ImageTooLargeError naming the image,
        ValueError for an `fx` that `focal_problem` refuses.

        whole: the image as one input; sliding: the window grid; proposals: object proposals.
        `fx`: the camera's focal length in pixels of the images (the calibration's camera
        matrix [0, 0] at the images' size), which the pose then uses instead of estimating it.
        """
        problem = self.focal_problem(mode, fx)
        if problem is not None:
            raise ValueError(problem)
        pixels = self.check_pixels(images, mode)
        try:
            if mode == "sliding":
                return self._detect(images, self.boxes, self.settings.sliding_resolution)
            if mode == "proposals":
                return self._detect(images, self._proposals, self.settings.proposals_resolution)
            return self._whole(images, fx)
        finally:
            if pixels > TRIM_ABOVE_PIXELS:
                give_back_memory()

    def _whole(self, images: Sequence[ImageInput], fx: float | None) -> Prediction:
        size, inputs, prep, frames, known = self.model.input_size, [], [], [], []
        zoom = self.settings.zoom and self.model.zooms
        detail: list[np.ndarray | None] = []  # the zoom pass's frames at 2x the input size
        # decoded the same with the pass off, so that the network input is made the same way
        decode = detail_decode_size(size)
        for i, image in enumerate(images):
            t0 = time.perf_counter()
            decoded = self._load(i, image, decode)
            inputs.append(to_network_input(decoded.rgb, size))
            if zoom:
                detail.append(detail_of(decoded.rgb, size))
            frames.append(NetworkFrame((decoded.width, decoded.height), size))
            known.append(self._known_focal(image[1], (decoded.width, decoded.height), fx))
            prep.append(time.perf_counter() - t0)
        aspect = np.array([f.pixel_aspect for f in frames], dtype=np.float32)
        focal = None  # 0 for an image: unknown, estimated (`PoseModel.run`)
        if any(k is not None for k in known):
            focal = np.array(
                [
                    0.0 if k is None else f.input_focal(k[0])
                    for f, k in zip(frames, known, strict=True)
                ],
                np.float32,
            )
        t0 = time.perf_counter()
        batch = np.stack(inputs)
        if zoom:
            cfg = self.settings
            answer = zoomed(
                self.model, batch, aspect, cfg.zoom_search, focal, detail, cfg.zoom_search_tiles
            )
        else:
            answer = self.model.run(batch, aspect, focal=focal)
        probs, corners, infer_s = answer.probabilities, answer.corners, time.perf_counter() - t0
        share = infer_s / len(images)
        results = []
        for i, (image, p, t, k) in enumerate(zip(images, probs, prep, known, strict=True)):
            result = _result(image[0], int(p.argmax()), p, t + share)
            if corners is not None and result.class_id != 0:
                result.corners = frames[i].to_image(corners[i]).tolist()
            if k is not None:
                result.fx, result.fx_source = k
            results.append(result)
        return Prediction(results, infer_s)

    def _known_focal(
        self, data: bytes, size: tuple[int, int], fx: float | None
    ) -> tuple[float, FocalSource] | None:
        """The focal length (px of an image of `size` (W, H)) the pose uses for it and where it
        came from: the request's `fx`, else its EXIF's (`exif_focal`), else None (estimated)."""
        if fx is not None:
            return fx, "query"
        if self.settings.exif_focal and self.model.takes_focal:
            exif_fx = exif_focal(data, size)
            if exif_fx is not None:
                return exif_fx, "exif"
        return None

    def _detect(
        self, images: Sequence[ImageInput], boxes_of: BoxGenerator, resolution: float
    ) -> Prediction:
        """Classify the boxes `boxes_of` finds in a working copy of each image (one batched
        call for all), keep the best window per image (NMS, class 0 windows dropped)."""
        size, cfg = self.model.input_size, self.settings
        min_size = working_min_size(size, resolution)
        staged, batches, prep = [], [], []
        for i, image in enumerate(images):
            t0 = time.perf_counter()
            decoded = self._load(i, image, min_size)
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
                image[0], answer.class_id, answer.probabilities, t + infer_s * len(boxes) / total
            )
            if answer.box is not None:
                result.box = _box(answer.box, scale, full)
            result.detections = [
                Detection(class_id=c, confidence=s, box=_box(b, scale, full))
                for b, c, s in answer.detections
            ]
            results.append(result)
            start += len(boxes)
        return Prediction(results, infer_s)
