"""The exported graph's contract: input and output names, shapes and defaults.

`train.network.export` writes graphs to it and `service.pipeline.model` reads them by it.

Inputs: `image` float32 [N, 3, H, W], RGB in [0, 1] (`service.core.preprocess`). The corner
networks also take three inputs with a default (overridable initializers, one row that
broadcasts over N): `pixel_aspect` [N], `view` [N, 3] and `focal` [N], described in
`OPTIONAL_INPUTS`.

Outputs: `probabilities` float32 [N, 9] (softmax, index = class id). The corner networks also
give `corners` float32 [N, 4, 2], the object's corners (u, v) in frame pixels in
`service.core.frame.CORNER_ORDER`, and `pattern` float32 [N], P(object present) from the
pattern at the corners alone (the zoom pass, `service.pipeline.zoom`), and (since 3.11.0)
`undistorted` float32 [N, 4, 2], the same corners without the lens's radial distortion the
network fitted (where a pinhole camera would see them: the pose's corners,
`service.pipeline.posing`). A graph with one output gives the probabilities whatever its name.
"""

from __future__ import annotations

import numpy as np

from service.core.frame import CORNER_ORDER
from service.core.regions import NUM_CLASSES

IMAGE = "image"
PIXEL_ASPECT, VIEW, FOCAL = "pixel_aspect", "view", "focal"
PROBABILITIES, CORNERS, PATTERN = "probabilities", "corners", "pattern"
UNDISTORTED = "undistorted"
#: The metadata_props key holding the model card (JSON).
CARD_KEY = "model_card"
#: The metadata_props key holding the object's front-on texture (a PNG, base64), which the
#: service aligns to the photo at its own resolution (`service.core.refine`).
TEXTURE_KEY = "texture_png"
#: A texture embedded in a model has at most this many px on its longer side.
TEXTURE_MAX_PX = 1024

#: (u0, v0, s): the input is the whole frame.
DEFAULT_VIEW = np.array([0.0, 0.0, 1.0], np.float32)
#: The optional inputs' defaults, one row each (broadcast over the batch).
DEFAULTS: dict[str, np.ndarray] = {
    PIXEL_ASPECT: np.ones(1, np.float32),
    VIEW: DEFAULT_VIEW[None],
    FOCAL: np.zeros(1, np.float32),
}
#: The optional inputs, as the model card describes them.
OPTIONAL_INPUTS = {
    PIXEL_ASPECT: "float32 [N], default 1, the height over the width of an input pixel in the "
    "scene (4/3 for a 16:9 photo resized to the input)",
    VIEW: "float32 [N, 3], default (0, 0, 1), where the input lies in the camera's frame: input "
    "pixel (u, v) is frame pixel (u0 + (u + 0.5) s - 0.5, v0 + (v + 0.5) s - 0.5)",
    FOCAL: "float32 [N], default 0 (unknown: self-calibrated), else the camera's focal length "
    "fx in frame pixels of the input's width",
}
#: The outputs, as the model card describes them.
OUTPUTS = {
    PROBABILITIES: f"float32 [N, {NUM_CLASSES}] (softmax), index = class id",
    CORNERS: "float32 [N, 4, 2], the object's corners (u, v) in frame pixels (input pixels "
    f"with the default view), order {CORNER_ORDER}",
    PATTERN: "float32 [N], P(object present) from the pattern at the corners alone",
    UNDISTORTED: "float32 [N, 4, 2], the corners without the lens's radial distortion the "
    "network fitted, frame pixels",
}


def io_description(corners: bool) -> dict[str, str]:
    """The model card's `input_format` and `output` for a graph with (or without) corners."""
    inputs = [
        f"{IMAGE}: float32 [N, 3, H, W], RGB, values in [0, 1] (portraits turned a quarter "
        "clockwise, resize with area)"
    ]
    outputs = [PROBABILITIES] + ([CORNERS, PATTERN, UNDISTORTED] if corners else [])
    if corners:
        inputs += [f"{name}: {text}" for name, text in OPTIONAL_INPUTS.items()]
    return {
        "input_format": "; ".join(inputs),
        "output": "; ".join(f"{name}: {OUTPUTS[name]}" for name in outputs),
    }
