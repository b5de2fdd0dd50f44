"""A request as the predictor takes it: its options checked once (`Options`) and its images'
headers read once (`Upload`), within the size limits, before any image is decoded (`admit`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from service.core.cells import RegionGrid
from service.core.preprocess import (
    ImageDecodeError,
    ImageHeader,
    ImageTooLargeError,
    decoded_pixels,
    image_header,
)
from service.pipeline.focal import KnownFocal
from service.pipeline.results import Mode

#: (filename or None, encoded image bytes)
ImageInput = tuple[str | None, bytes]


class PixelBudgetError(ImageTooLargeError):
    """The images of one request would decode to more pixels than its budget
    (`Settings.max_request_pixels`): refused from their headers, before any is decoded."""


def too_large_code(exc: ImageTooLargeError) -> str:
    """The error code of a refusal by size: the request's budget or one image's limit."""
    return "pixel_budget_exceeded" if isinstance(exc, PixelBudgetError) else "image_too_large"


@dataclass(frozen=True)
class Options:
    """What a request asks for, accepted by `Predictor.options` (the focal length's range and
    use checked there, once): the mode, a known focal length or a same-camera fit (whole
    mode), the finer regions each pose's `cell` is named in."""

    mode: Mode = "whole"
    focal: KnownFocal | None = None
    same_camera: bool = False
    grid: RegionGrid | None = None


@dataclass(frozen=True)
class Upload:
    """One image of a request: its place, name, bytes and header (read once, `admit`)."""

    index: int
    filename: str | None
    data: bytes
    header: ImageHeader

    @property
    def name(self) -> str:
        """How errors name it: `image 2 (name.jpg)`."""
        return _name(self.index, self.filename)


def _name(index: int, filename: str | None) -> str:
    return f"image {index + 1}" + (f" ({filename})" if filename else "")


@dataclass(frozen=True)
class Job:
    """A request the predictor admitted: its images and options, and the pixels the images
    decode to."""

    uploads: list[Upload]
    options: Options
    pixels: int


def admit(
    images: Sequence[ImageInput],
    options: Options,
    min_size: tuple[int, int],
    max_pixels: int,
    max_request_pixels: int,
) -> Job:
    """The images of one request read from their headers, decoded later at `min_size` at
    least (a large JPEG is decoded reduced down to it); ImageDecodeError (naming the image)
    for a header that is not an image's, ImageTooLargeError for an image above `max_pixels`,
    PixelBudgetError when all of them are above `max_request_pixels`."""
    uploads, total, largest = [], 0, (0, "")
    for i, (filename, data) in enumerate(images):
        try:
            header = image_header(data)
        except ImageDecodeError as exc:
            raise ImageDecodeError(f"{_name(i, filename)}: {exc}") from None
        stored = header.width * header.height
        if stored > max_pixels:
            raise ImageTooLargeError(
                f"{_name(i, filename)}: image is {header.width}x{header.height} = {stored} "
                f"pixels, more than the limit of {max_pixels}"
            )
        pixels = decoded_pixels(header, min_size)
        total += pixels
        largest = max(largest, (pixels, f"{header.width}x{header.height}"))
        uploads.append(Upload(i, filename, data, header))
    if total > max_request_pixels:
        raise PixelBudgetError(
            f"{len(images)} image(s), the largest {largest[1]}, decode to {total} pixels, "
            f"more than the budget of {max_request_pixels} pixels per request"
        )
    return Job(uploads, options, total)
