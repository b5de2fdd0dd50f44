"""Object proposals for the objectness mode (SPEC section 9): boxes likely to hold an object.

opencv-python-headless has no ximgproc (no selective search, no edge boxes), so this is a
small alternative built from core OpenCV, in the spirit of edge boxes:

1. The image is shrunk so its longer side is at most `WORK_SIDE` pixels (speed).
2. Candidate regions come from two sources: MSER regions (stable blobs of uniform grey,
   e.g. the squares of a board or a cover's patches) and Canny edges closed with square
   kernels of several sizes, whose external contours group nearby edges into objects at
   several scales. Each candidate is its bounding rectangle; the whole image is one too.
3. Every candidate is grown by `MARGIN` on each side, widened or heightened about its centre
   to the network's aspect ratio (w / h), and fitted into the image (shrunk if larger, with
   the aspect kept, then shifted inside). Boxes smaller than `MIN_SIDE` of the image's
   shorter side are dropped.
4. Score (edge-box style): the share of edge pixels inside the box minus the share in a ring
   around it (half the box's size), so boxes that enclose a textured object in a calmer
   surrounding win over boxes that cut through texture.
5. Non-maximum suppression at IoU `NMS_IOU` (`cv2.dnn.NMSBoxes`) removes near duplicates;
   the best `max_boxes` remain, best first.

Pure numpy + OpenCV, deterministic (no randomness), no service or training imports.
"""

from __future__ import annotations

import cv2
import numpy as np

WORK_SIDE = 320
MARGIN = 0.1
MIN_SIDE = 0.2
NMS_IOU = 0.6
CLOSE_KERNELS = (3, 7, 15)


def _candidates(grey: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Bounding rectangles (N, 4) x, y, w, h of MSER regions and closed-edge contours."""
    h, w = grey.shape
    area = h * w
    mser = cv2.MSER.create(min_area=max(16, area // 2000), max_area=area // 2)
    _, mser_boxes = mser.detectRegions(grey)
    boxes = [np.asarray(mser_boxes, dtype=np.int64).reshape(-1, 4)]
    for k in CLOSE_KERNELS:
        closed = cv2.morphologyEx(edges, cv2.MORPH_CLOSE, np.ones((k, k), np.uint8))
        contours, _ = cv2.findContours(closed, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        rects = [cv2.boundingRect(c) for c in contours]
        boxes.append(np.asarray(rects, dtype=np.int64).reshape(-1, 4))
    boxes.append(np.array([[0, 0, w, h]], dtype=np.int64))
    return np.concatenate(boxes)


def fit_aspect(
    boxes: np.ndarray, aspect: float, size: tuple[int, int], margin: float = MARGIN
) -> np.ndarray:
    """Boxes (N, 4) x, y, w, h (float) grown by `margin`, made w / h = `aspect` about their
    centre, then fitted into an image of `size` (W, H): shrunk (aspect kept) if too large
    and shifted inside. Returns float boxes (N, 4)."""
    W, H = size
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    cx, cy = b[:, 0] + b[:, 2] / 2, b[:, 1] + b[:, 3] / 2
    w, h = b[:, 2] * (1 + 2 * margin), b[:, 3] * (1 + 2 * margin)
    w, h = np.maximum(w, h * aspect), np.maximum(h, w / aspect)
    shrink = np.minimum(1.0, np.minimum(W / w, H / h))
    w, h = w * shrink, h * shrink
    x = np.clip(cx - w / 2, 0, W - w)
    y = np.clip(cy - h / 2, 0, H - h)
    return np.column_stack([x, y, w, h])


def _box_sums(integral: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Sums of the image whose integral image is `integral` over integer boxes (N, 4)."""
    x0, y0 = boxes[:, 0], boxes[:, 1]
    x1, y1 = x0 + boxes[:, 2], y0 + boxes[:, 3]
    sums: np.ndarray = integral[y1, x1] - integral[y0, x1] - integral[y1, x0] + integral[y0, x0]
    return sums


def edge_scores(edges: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Edge share inside each integer box (N, 4) minus the edge share of the ring around it
    (the box grown by half its size, clipped to the image)."""
    h, w = edges.shape
    integral = cv2.integral((edges > 0).astype(np.uint8)).astype(np.float64)
    inner = _box_sums(integral, boxes)
    inner_area = np.maximum(boxes[:, 2] * boxes[:, 3], 1)
    x0 = np.clip(boxes[:, 0] - boxes[:, 2] // 4, 0, w)
    y0 = np.clip(boxes[:, 1] - boxes[:, 3] // 4, 0, h)
    x1 = np.clip(boxes[:, 0] + boxes[:, 2] + boxes[:, 2] // 4, 0, w)
    y1 = np.clip(boxes[:, 1] + boxes[:, 3] + boxes[:, 3] // 4, 0, h)
    outer_boxes = np.column_stack([x0, y0, x1 - x0, y1 - y0])
    ring = _box_sums(integral, outer_boxes) - inner
    ring_area = np.maximum(outer_boxes[:, 2] * outer_boxes[:, 3] - inner_area, 1)
    scores: np.ndarray = inner / inner_area - ring / ring_area
    return scores


def propose_boxes(rgb: np.ndarray, aspect: float, max_boxes: int) -> np.ndarray:
    """Object proposals for an RGB uint8 image [H, W, 3]: int array (N <= max_boxes, 4) of
    x, y, w, h in pixels, best first. Every box lies inside the image and has w / h equal
    to `aspect` up to pixel rounding (unless the image is too small for it)."""
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"expected an RGB uint8 image [H, W, 3], got {rgb.dtype} {rgb.shape}")
    if not aspect > 0 or max_boxes < 1:
        raise ValueError(f"need aspect > 0 and max_boxes >= 1, got {aspect}, {max_boxes}")
    H, W = rgb.shape[:2]
    scale = min(1.0, WORK_SIDE / max(H, W))
    small = cv2.resize(rgb, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    grey = cv2.cvtColor(small, cv2.COLOR_RGB2GRAY)
    median = float(np.median(grey))
    edges = cv2.Canny(cv2.GaussianBlur(grey, (3, 3), 0), 0.66 * median, 1.33 * median + 1)
    h, w = grey.shape

    raw = _candidates(grey, edges)
    min_side = MIN_SIDE * min(h, w)
    boxes = np.round(fit_aspect(raw, aspect, (w, h))).astype(np.int64)
    boxes[:, 2:] = np.maximum(boxes[:, 2:], 1)
    boxes = boxes[(boxes[:, 2] >= min_side * aspect) | (boxes[:, 3] >= min_side)]
    boxes = np.unique(boxes, axis=0)  # sorted rows: the order below is deterministic
    scores = edge_scores(edges, boxes)
    order = np.lexsort((np.arange(len(boxes)), -scores))
    boxes, scores = boxes[order], scores[order]
    # NMSBoxes wants scores >= its threshold (0): shift them from [-1, 1] to [0, 2].
    shifted = (scores + 1.0).tolist()
    keep = cv2.dnn.NMSBoxes(boxes.tolist(), shifted, 0.0, NMS_IOU, top_k=max_boxes)
    kept = boxes[np.asarray(keep, dtype=np.int64).ravel()][:max_boxes]

    # Back to the original image's pixels, with the aspect re-imposed after rounding.
    full = fit_aspect(kept.astype(np.float64) / scale, aspect, (W, H), margin=0.0)
    out = np.round(full).astype(np.int64)
    out[:, 2] = np.clip(out[:, 2], 1, W - out[:, 0])
    out[:, 3] = np.clip(out[:, 3], 1, H - out[:, 1])
    return out
