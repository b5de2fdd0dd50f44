"""A `/v1/predict` request -> the images it carries: multipart field `image` (one or many) or
one raw body with an image content type."""

from __future__ import annotations

from typing import Any

from fastapi import Request
from starlette.datastructures import UploadFile
from starlette.exceptions import HTTPException as StarletteHTTPException

from service.api.errors import ApiError
from service.core.preprocess import SUPPORTED_FORMATS
from service.pipeline.job import ImageInput

#: Raw-body content types accepted (the bytes are sniffed anyway).
IMAGE_TYPES = frozenset(
    {
        "image/jpeg",
        "image/jpg",
        "image/png",
        "image/webp",
        "image/bmp",
        "image/x-ms-bmp",
        "image/gif",
    }
)
#: Content types accepted on a multipart part (curl sends octet-stream for unknown suffixes).
PART_TYPES = IMAGE_TYPES | {"application/octet-stream", ""}


def _media_type(value: str | None) -> str:
    return (value or "").split(";", 1)[0].strip().lower()


def _unsupported(what: str, media: str) -> ApiError:
    return ApiError(
        415,
        "unsupported_media_type",
        f"{what} has content type {media or '(none)'}: send multipart/form-data with field "
        f"'image', or one raw image body (image/jpeg, image/png, image/webp, image/bmp, "
        f"image/gif; {SUPPORTED_FORMATS})",
    )


async def _multipart(request: Request, max_images: int) -> list[ImageInput]:
    try:
        form = await request.form(max_files=max_images, max_fields=max_images + 8)
    except StarletteHTTPException as exc:
        if "Too many files" in str(exc.detail):
            raise ApiError(
                413, "too_many_images", f"more than {max_images} images in one request"
            ) from None
        raise ApiError(400, "bad_request", f"malformed multipart body: {exc.detail}") from None
    try:
        parts = form.getlist("image")
        if not parts:
            raise ApiError(
                422, "invalid_parameters", "no image: send files in multipart field 'image'"
            )
        images: list[ImageInput] = []
        for part in parts:
            if not isinstance(part, UploadFile):
                raise ApiError(422, "invalid_parameters", "field 'image' must be a file part")
            media = _media_type(part.content_type)
            if media not in PART_TYPES:
                raise _unsupported(f"part {part.filename or '(unnamed)'}", media)
            images.append((part.filename or None, await part.read()))
        return images
    finally:
        await form.close()


async def read_images(request: Request, max_images: int) -> list[ImageInput]:
    """The (filename, bytes) pairs of the request, or ApiError 413/415/422."""
    media = _media_type(request.headers.get("content-type"))
    if media == "multipart/form-data":
        return await _multipart(request, max_images)
    if media in IMAGE_TYPES:
        return [(None, await request.body())]
    raise _unsupported("the request", media)


def images_form(description: str) -> dict[str, Any]:
    """The OpenAPI schema of a multipart body of one or many images in the field `image`
    (`read_images` reads it), the field described by `description`."""
    image = {"type": "array", "items": {"type": "string", "format": "binary"}}
    return {
        "schema": {
            "type": "object",
            "properties": {"image": {**image, "description": description}},
            "required": ["image"],
        }
    }
