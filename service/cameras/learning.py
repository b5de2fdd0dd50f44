"""A camera learned from photos of the object (`POST /v1/cameras` multipart): the corners the
predictor finds and refines in them, fitted by `service.core.calibration.fit_camera`, and
stored (`learn_into`)."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from service.cameras.schema import CameraOut
from service.cameras.store import CameraStore
from service.core.calibration import fit_camera
from service.core.frame import object_corners
from service.core.preprocess import camera_pixels
from service.pipeline.predictor import Predictor

#: Photos of the object a camera is learned from, at least.
MIN_PHOTOS = 3


def learn_into(
    store: CameraStore,
    predictor: Predictor,
    images: list[tuple[str | None, bytes]],
    name: str | None = None,
) -> CameraOut:
    """Photos of the object by one camera -> the camera learned from them (`learn_camera`),
    stored as `name`; ValueError why it cannot be learned, the store's errors
    (CameraStoreFull, CameraStoreError) and the predictor's for an image it refuses."""
    return store.create({**learn_camera(predictor, images), "name": name})


def learn_camera(predictor: Predictor, images: list[tuple[str | None, bytes]]) -> dict[str, Any]:
    """Photos of the object by one camera -> the camera's fields (`fit_camera` of the
    corners found and refined in them: fx, and the lens where the photos pin it);
    ValueError saying why it cannot be learned."""
    size_cm = predictor.model.object_size_cm
    if size_cm is None or predictor.model.corners_name is None:
        raise ValueError(f"model {predictor.model.name} gives no corners: pick a corner model")
    prediction = predictor.predict(images, "whole")
    found = [
        ((r.image_size[0], r.image_size[1]), q, kappa, points)
        for r, q, kappa, points in zip(
            prediction.results,
            prediction.pinhole,
            prediction.kappas,
            prediction.features,
            strict=True,
        )
        if q is not None and r.image_size is not None
    ]
    if len(found) < MIN_PHOTOS:
        raise ValueError(
            f"the object was found in {len(found)} of {len(images)} photos; "
            f"{MIN_PHOTOS} or more are needed"
        )
    w, h = max(found[0][0]), min(found[0][0])  # landscape: portraits are the camera turned
    odd = sorted({size for size, _, _, _ in found if sorted(size) != [h, w]})
    if odd:
        raise ValueError(
            f"photos of {w}x{h} and of {', '.join(f'{a}x{b}' for a, b in odd)}: "
            "send one camera's photos, all of one size"
        )
    # a portrait is the camera turned: its corners turned back to landscape (fx and a centred
    # principal point stay)
    views = [camera_pixels(q, size, (w, h)) for size, q, _, _ in found]
    features = [
        None if p is None else replace(p, seen=camera_pixels(p.seen, size, (w, h)))
        for size, _, _, p in found
    ]
    kappas = [k for _, _, k, _ in found]
    fit = fit_camera(views, kappas, object_corners(*size_cm, z=True), (w, h), features)
    used = int(fit.used.sum())
    if used < MIN_PHOTOS or not fit.pinned:
        raise ValueError(
            f"the {used} photos that fit leave fx between {fit.fx_range[0]:.0f} and "
            f"{fit.fx_range[1]:.0f} px: add photos that view the object obliquely "
            "(tilted 20-50 degrees), from several sides"
        )
    cx, cy = (None, None) if fit.centre is None else (round(v, 3) for v in fit.centre)
    return {
        "fx": round(fit.fx, 3),
        "cx": cx,
        "cy": cy,
        "dist": None if fit.dist is None else [round(v, 6) for v in fit.dist],
        "width": w,
        "height": h,
        "source": "photos",
        "photos_used": used,
        "residual_px": round(fit.residual_px, 3),
        "fx_range": [round(v, 3) for v in fit.fx_range],
        "k1_se": None if fit.k1_se is None else round(fit.k1_se, 4),
    }
