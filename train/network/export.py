"""Export a training checkpoint to ONNX with its model card (SPEC section 8; docs/architecture.md).

The graph takes `image` float32 [N, 3, H, W], RGB in [0, 1] (dynamic N; the normalisation is
inside) and returns `probabilities` float32 [N, 9] (softmax); the corner networks also take
`pixel_aspect` float32 [N] (an input with the default [1], an overridable initializer: a
caller that feeds only `image` gets square pixels), `view` float32 [N, 3] (default
[[0, 0, 1]]: the input is the camera's whole frame; `train.network.corners.CornerNet.answer`
says what a crop's view is) and `focal` float32 [N] (default [0]: unknown, self-calibrated;
else the camera's focal length in frame pixels of the input's width), and return `corners`
float32 [N, 4, 2], the object's image corners in frame pixels in
`service.core.frame.CORNER_ORDER`, and `pattern` float32 [N], P(present) from
the checker pattern at the corners alone (`service.pipeline.zoom` uses both). The model card (JSON)
is stored in the ONNX `metadata_props` under `model_card` and written next to it as
`<name>.json`.
"""

from __future__ import annotations

import base64
import io
import json
import warnings
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from service.core.dataset import load_dataset, read_manifest
from service.core.onnx_contract import (
    CARD_KEY,
    CORNERS,
    DEFAULTS,
    FOCAL,
    IMAGE,
    PATTERN,
    PIXEL_ASPECT,
    PROBABILITIES,
    TEXTURE_KEY,
    TEXTURE_MAX_PX,
    UNDISTORTED,
    VIEW,
    io_description,
)
from service.core.paths import REPO_ROOT
from service.core.pose import FOCAL_BOUNDS
from service.core.profile import focal_prior_of, load_profile
from service.core.regions import NUM_CLASSES, Z_SPLIT_CM, class_descriptions, region_of_class
from train.network.config import CORNER_ARCHS, canonical_arch

OPSET = 17
#: What the card says of each architecture (train.network.model.build_network).
ARCHITECTURES = {
    "spec": "spec: the SPEC section 8 network (tanh, L2 pooling), batch norm folded away",
    "convnet": "convnet: train/network/convnet.py (ReLU, batch norm, max pooling, 3x4 head)",
    "corners-coarse": "corners-coarse: train/network/corners.py (U-Net corner heat maps, "
    "corners aligned to the object's texture, class from the corners' pose with a prior camera "
    "and the texture's half turn)",
    "corners": "corners: train/network/corners.py with corner heat maps at 80x60 "
    "(stride 2), corners aligned to the object's texture (train/network/align.py)",
    "corners-any": "corners-any: train/network/anynet.py, the corner network (stride 2) "
    "conditioned on the object's picture, baked into the graph; one set of weights for any "
    "object, trained on many textures",
}


def onnx_bytes(net: Any) -> bytes:
    """Serialise a pose network (eval mode) to ONNX bytes, dynamic batch: output
    `probabilities` (softmax); the corner networks also take `pixel_aspect` (default 1),
    `view` (default (0, 0, 1)) and `focal` (default 0) and output `corners`, `pattern` and
    `undistorted`."""
    import onnx
    import torch

    from train.network.model import Probabilities, takes_pixel_aspect

    w, h = net.size
    wrapper = Probabilities(net).eval()
    corner = takes_pixel_aspect(net)
    image = torch.rand(2, 3, h, w)
    if corner:
        inputs = [IMAGE, PIXEL_ASPECT, VIEW, FOCAL]
        outputs = [PROBABILITIES, CORNERS, PATTERN, UNDISTORTED]
        defaults = DEFAULTS
        example: tuple[Any, ...] = (image, *(torch.from_numpy(v) for v in defaults.values()))
    else:
        inputs, outputs, defaults, example = [IMAGE], [PROBABILITIES], {}, (image,)
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        torch.onnx.export(
            wrapper,
            example,
            buf,  # type: ignore[arg-type]  # a file object is accepted (torch.onnx.export doc)
            dynamo=False,
            input_names=inputs,
            output_names=outputs,
            # the defaults' own batch dimension: a default of one row broadcasts over any N
            dynamic_axes={name: {0: "N"} for name in [IMAGE, *outputs]}
            | {name: {0: f"N_{name}"} for name in defaults},
            opset_version=OPSET,
        )
    if not defaults:
        return buf.getvalue()
    model = onnx.load_from_string(buf.getvalue())
    for name, value in defaults.items():  # graph inputs with a default: overridable
        model.graph.initializer.append(onnx.numpy_helper.from_array(value, name))
    return model.SerializeToString()


def profile_card(profile: dict[str, Any]) -> dict[str, Any]:
    """The object profile part of the card from a data set manifest's profile (+ its file).

    Adds the camera box and roll range from the profile definition when it can be loaded;
    `texture` is given relative to the repository root when it lies inside it.
    """
    card = dict(profile)
    try:
        full = load_profile(profile["name"])
        card.setdefault("box_min_cm", list(full.geometry.box_min))
        card.setdefault("box_max_cm", list(full.geometry.box_max))
        card.setdefault("roll_max_deg", float(full.roll_max_deg))
    except (ImportError, KeyError, FileNotFoundError, ValueError, AttributeError):
        pass  # the manifest's own fields stay; the card says what is known
    texture = card.get("texture")
    if texture:
        path = Path(texture)
        path = path if path.is_absolute() else (REPO_ROOT / path)
        try:
            card["texture"] = path.resolve().relative_to(REPO_ROOT).as_posix()
        except ValueError:
            card["texture"] = str(texture)
    return card


def _data_summary(data: list[dict[str, Any]]) -> list[dict[str, Any]]:
    keys = ("path", "split", "count", "variant", "size", "blur", "seed", "real")
    return [{k: d[k] for k in keys if k in d} for d in data]


def _camera_card(profile: dict[str, Any]) -> dict[str, Any]:
    """The corner graph's camera model (`train.network.corners`): constants of the geometry
    after the corners, baked into the graph when it is exported (docs/camera_model.md); the
    focal-length prior is the object's (its card's `profile`, `service.core.profile`)."""
    from train.network import corners as corner_net
    from train.network.align import TextureAlign

    align = TextureAlign(corner_net.SIZE)
    return {
        "focal_prior_x_spec": focal_prior_of(profile),
        "focal_prior_weight": corner_net.FOCAL_PRIOR_WEIGHT,
        "focal_bounds_x_spec": list(FOCAL_BOUNDS),
        # a fitted k1 below it shortens the focal prior (`CornerNet.prior_focal`)
        "focal_prior_barrel_limit": corner_net.BARREL_LIMIT,
        "radial_k1": corner_net.RADIAL_PRIOR,
        # k1 fitted per image by the corner alignment around that prior (train/network/align.py)
        "radial_fit": {
            "prior_sd": align.radial_sd,
            "range": list(align.k1_range),
            "min_pattern_corr": align.k1_min_corr,
        },
        "principal_point": "image centre",
        "radial_model": RADIAL_MODEL,
    }


def _io_card(corner: bool, profile: dict[str, Any]) -> dict[str, Any]:
    """The card's `input_format` and `output`: the graph's inputs and outputs (module doc),
    and for a corner graph its `camera_model` (of the card's `profile`)."""
    camera = {"camera_model": _camera_card(profile)} if corner else {}
    return camera | io_description(corner)


def build_card(
    name: str,
    checkpoint: dict[str, Any],
    accuracy: dict[str, dict[str, Any]],
    version: str,
    notes: str,
) -> dict[str, Any]:
    """The model card dict (see module doc) from a checkpoint written by `train.network.fit`."""
    profile = profile_card(checkpoint.get("profile", {}))
    z_split = float(profile.get("z_split_cm", Z_SPLIT_CM))
    descriptions = class_descriptions(z_split)
    arch = canonical_arch(checkpoint.get("arch", "spec"))
    corner = arch in CORNER_ARCHS
    training: dict[str, Any] = {
        "data": _data_summary(checkpoint.get("data", [])),
        "seed": checkpoint["config"].get("seed"),
        "best_epoch": checkpoint.get("best", {}),  # the epoch whose weights these are
        "config": {
            k: checkpoint["config"].get(k)
            for k in (
                "epochs",
                "batch_size",
                "optimizer",
                "lr",
                "schedule",
                "augment",
                "repeat",
                "select",
                "corner_weight",
            )  # fmt: skip
        },
        "recipe": checkpoint["config"].get("extra", {}).get("recipe"),
    }
    if rebuild := checkpoint["config"].get("extra", {}).get("rebuild"):
        training["rebuild"] = rebuild  # the commands that make the model again
    parent = checkpoint.get("parent")
    if parent:
        training["fine_tuned_from"] = {
            "data": _data_summary(parent.get("data", [])),
            "seed": parent.get("config", {}).get("seed"),
            "epochs": parent.get("config", {}).get("epochs"),
            "best_epoch": parent.get("best", {}),
        }
    return {
        "name": name,
        "version": version,
        "date": datetime.now(UTC).isoformat(timespec="seconds"),
        "architecture": ARCHITECTURES[arch],
        "input": list(checkpoint["size"]),
        **_io_card(corner, profile),
        "classes": [
            {"id": k, "label": region_of_class(k)["label"], "description": descriptions[k]}
            for k in range(NUM_CLASSES)
        ],
        "profile": profile,
        "training": training,
        "accuracy": accuracy,
        "notes": notes,
    }


def texture_png(card: dict[str, Any]) -> bytes | None:
    """The card's object texture (its profile's `texture`, a repository path) as PNG bytes,
    its longer side at most `TEXTURE_MAX_PX`, or None for a card without a readable one."""
    import cv2

    texture = (
        card.get("profile", {}).get("texture") if isinstance(card.get("profile"), dict) else None
    )
    path = REPO_ROOT / str(texture) if texture else None
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR) if path is not None and path.is_file() else None
    if bgr is None:
        return None
    f = TEXTURE_MAX_PX / max(bgr.shape[:2])
    if f < 1:
        bgr = cv2.resize(bgr, None, fx=f, fy=f, interpolation=cv2.INTER_AREA)
    ok, png = cv2.imencode(".png", bgr)
    return png.tobytes() if ok else None


#: The lens convention of the card's `radial_k1` and the graph's fitted k1 (not OpenCV's).
RADIAL_MODEL = (
    "division: x_u = x_d / (1 + k1 |x_d|^2), x in normalised coordinates of the prior focal "
    "length about the image centre (not OpenCV's polynomial; the service's refinement fits "
    "its own, service/core/refine.py RadialLens)"
)
#: A card's `role`: the model to use for its object, or one kept for the measured pages.
ROLES = ("pick", "ablation")
#: Folders of the repository that moved since older cards were written: old -> new prefix.
MOVED = {"train/profiles/": "train/assets/profiles/"}


def repo_path(path: Path) -> str:
    """`path` as a card records it: relative to the repository where it lies inside it (so
    that a card names no folder of the machine it was made on), else as given."""
    try:
        return Path(path).resolve().relative_to(REPO_ROOT).as_posix()
    except ValueError:
        return str(path)


def amend_card(
    onnx_path: Path,
    recipe: str | None = None,
    rebuild: list[str] | None = None,
    role: str | None = None,
    use: str | None = None,
    notes: str | None = None,
) -> dict[str, Any]:
    """Rewrite a model's card in its ONNX metadata and in its `.json` beside it, the graph
    unchanged: the training's `recipe` (a file in recipes/) and `rebuild` (the commands that
    make the model again), its `role` (`ROLES`) and `use` (when to pick it), its notes; the
    `architecture` text is this version's for the card's network and a texture path in a
    folder that moved is the new one (`MOVED`) -> the card."""
    import onnx

    model = onnx.load(str(onnx_path))
    cards = [p.value for p in model.metadata_props if p.key == CARD_KEY]
    if not cards:
        raise ValueError(f"{onnx_path} has no model card in its metadata")
    card = json.loads(cards[0])
    if role is not None and role not in ROLES:
        raise ValueError(f"role must be one of {', '.join(ROLES)}, got {role!r}")
    training = card.setdefault("training", {})
    if recipe is not None:
        training["recipe"] = recipe
    if rebuild is not None:
        training["rebuild"] = rebuild
    card |= {k: v for k, v in (("role", role), ("use", use), ("notes", notes)) if v is not None}
    texture = card.get("profile", {}).get("texture", "")
    for old, new in MOVED.items():
        if texture.startswith(old):
            card["profile"]["texture"] = new + texture[len(old) :]
    arch = canonical_arch(card.get("architecture", "spec").split(":")[0])  # cards before 2.0: spec
    card["architecture"] = ARCHITECTURES[arch]
    if isinstance(card.get("camera_model"), dict):  # the convention of its k1, stated
        card["camera_model"]["radial_model"] = RADIAL_MODEL
    onnx_path.write_bytes(with_card(onnx_path.read_bytes(), card))
    onnx_path.with_suffix(".json").write_text(json.dumps(card, indent=1) + "\n")
    return card


def with_card(model_bytes: bytes, card: dict[str, Any]) -> bytes:
    """ONNX bytes with `model_card` = card JSON set in metadata_props, and for a corner
    graph `texture_png` = the object's texture (`texture_png`; one the graph carries
    already is kept where the card's profile has none at hand)."""
    import onnx

    model = onnx.load_from_string(model_bytes)
    kept = {p.key: p.value for p in model.metadata_props}
    del model.metadata_props[:]
    entries = {CARD_KEY: json.dumps(card)}
    png = texture_png(card) if any(o.name == CORNERS for o in model.graph.output) else None
    if png is not None:
        entries[TEXTURE_KEY] = base64.b64encode(png).decode("ascii")
    elif TEXTURE_KEY in kept:
        entries[TEXTURE_KEY] = kept[TEXTURE_KEY]
    for key, value in entries.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    model.producer_name = "planar-pose"
    return model.SerializeToString()


def accuracy_on(predict: Any, datasets: list[Path], split: str) -> dict[str, dict[str, Any]]:
    """{data set folder name: {accuracy, class0_accuracy, count, split, by_margin,
    by_framing[, by_source]}} of a predictor (`train.network.evaluate.compute_metrics`; real
    sets: `source_breakdown`)."""
    from train.network.evaluate import compute_metrics, predict_all, source_breakdown

    out: dict[str, dict[str, Any]] = {}
    for path in datasets:
        data = load_dataset(path, split=None if split == "all" else split)
        if len(data.labels) == 0:
            raise ValueError(f"{path} has no images in split {split!r}")
        probs, ms = predict_all(predict, data.images, data.pixel_aspect())
        predicted = probs.argmax(axis=1)
        m = compute_metrics(data.labels, predicted, ms, data.boundary_margin_cm(), data.board_cut())
        out[path.name] = {
            "split": split,
            "count": m["count"],
            "accuracy": round(m["accuracy"], 4),
            "class0_accuracy": m["per_class_accuracy"][0],
            "by_margin": m["by_margin"],
            "by_framing": m["by_framing"],
        }
        if by_source := source_breakdown(data.labels, predicted, data.rows):  # a real set
            out[path.name]["by_source"] = by_source
    return out


#: Images an evaluation must have for the graph to be optimized for it first: optimizing a
#: corner graph costs ~3 s of CPU and saves ~5 ms per image.
OPTIMIZE_FROM_IMAGES = 600


def image_count(datasets: list[Path], split: str) -> int:
    """The images of `split` in the data sets, from their manifests (0 where not stated)."""
    total = 0
    for path in datasets:
        manifest = read_manifest(path)
        counts = manifest.get("counts") if split != "all" else None
        total += int(counts.get(split, 0) if isinstance(counts, dict) else manifest.get("count", 0))
    return total


def graph_predictor(raw: bytes, card: dict[str, Any], images: int) -> Any:
    """A `train.network.evaluate.Predictor` on ONNX bytes as the service answers with them
    (`service.pipeline.PoseModel`, the zoom pass where the graph serves it), for `images`
    images: the graph optimized first where they are `OPTIMIZE_FROM_IMAGES` or more (the
    answers agree to ~1e-5 either way)."""
    from service.pipeline import PoseModel
    from train.network.evaluate import model_predictor

    path, optimize = Path(f"{card['name']}.onnx"), images >= OPTIMIZE_FROM_IMAGES
    model = PoseModel.load(path, intra_op_threads=0, graph=(raw, card), optimize=optimize)
    return model_predictor(model)


def with_current_prior(profile: dict[str, Any]) -> dict[str, Any]:
    """A card's profile entry with the focal prior its profile file states now (a prior
    chosen after training reaches a regraphed model and its card); as it was where the
    profile cannot be loaded."""
    try:
        return profile | {"focal_prior": load_profile(profile["name"]).focal_prior}
    except (KeyError, FileNotFoundError, ValueError):  # ProfileError is a ValueError
        return profile


def regraph(onnx_path: Path, profile: dict[str, Any] | None = None) -> bytes:
    """A shipped corner graph exported again from its own weights
    (`train.network.onnx_weights`) in this version's form (`onnx_bytes`: the inputs and
    outputs of the zoom pass), its camera model that of `profile` (a card's profile entry;
    None: its own card's)."""
    from train.network.model import export_form
    from train.network.onnx_weights import corner_net_from_onnx

    net, _ = corner_net_from_onnx(onnx_path, profile)
    return onnx_bytes(export_form(net))


def export(
    checkpoint_path: Path,
    name: str,
    out_dir: Path,
    eval_datasets: list[Path] | None = None,
    split: str = "test",
    version: str = "1.0.0",
    notes: str = "",
    val_datasets: list[Path] | None = None,
) -> tuple[Path, dict[str, Any]]:
    """Write out_dir/<name>.onnx and out_dir/<name>.json -> (onnx path, card).

    Accuracy on `eval_datasets` (their `split`) and on the val split of `val_datasets` (the
    card's `accuracy_val`: what the model was selected on) is measured with onnxruntime on
    the exported graph itself.
    """
    from train.network.fit import load_network
    from train.network.model import export_form

    trained, checkpoint = load_network(checkpoint_path)
    net = export_form(trained)
    raw = onnx_bytes(net)
    images = image_count(eval_datasets or [], split) + image_count(val_datasets or [], "val")
    predict = graph_predictor(raw, {"name": name, "input": list(net.size)}, images)
    accuracy = accuracy_on(predict, eval_datasets, split) if eval_datasets else {}
    card = build_card(name, checkpoint, accuracy, version, notes)
    if val_datasets:
        card["accuracy_val"] = accuracy_on(predict, val_datasets, "val")
    out_dir.mkdir(parents=True, exist_ok=True)
    onnx_path = out_dir / f"{name}.onnx"
    onnx_path.write_bytes(with_card(raw, card))
    (out_dir / f"{name}.json").write_text(json.dumps(card, indent=1) + "\n")
    return onnx_path, card


def recard(
    onnx_path: Path,
    name: str,
    out_dir: Path,
    eval_datasets: list[Path],
    split: str = "test",
    notes: str | None = None,
    version: str | None = None,
    val_datasets: list[Path] | None = None,
) -> tuple[Path, dict[str, Any]]:
    """Measure a shipped ONNX model again on `eval_datasets` (and the val split of
    `val_datasets`, `export`) and write it with its card's accuracies replaced (training
    provenance unchanged; val figures it is not measured on again are dropped) as
    out_dir/<name>.onnx + .json. With a `version`, a corner graph is first exported again
    from its weights in this version's form (`regraph`, the focal prior its profile states
    now: `with_current_prior`) and its card says so, the command among its rebuild steps.
    Without `eval_datasets` (and no `version`) the model is only renamed: graph, accuracies
    and dates unchanged, `renamed_from` in the card."""
    import onnx

    model = onnx.load(str(onnx_path))
    cards = [p.value for p in model.metadata_props if p.key == CARD_KEY]
    if not cards:
        raise ValueError(f"{onnx_path} has no model card in its metadata")
    card = json.loads(cards[0])
    raw = onnx_path.read_bytes()
    if version is not None:
        profile = with_current_prior(card.get("profile", {}))
        raw = regraph(onnx_path, profile)
        regraphed = {"version": version, "regraphed_from": card.get("version")}
        card |= regraphed | {"profile": profile} | _io_card(True, profile)
        sets = [f"--eval {repo_path(p)}" for p in eval_datasets]
        sets += [f"--eval-val {repo_path(p)}" for p in val_datasets or []]
        command = f"planar-pose export {repo_path(onnx_path)} --name {name} --regraph"
        training = card.setdefault("training", {})
        rebuild = training.get("rebuild") or []
        training["rebuild"] = [*rebuild, " ".join([command, f"--version {version}", *sets])]
    if eval_datasets:
        card |= {"name": name}
        images = image_count(eval_datasets, split) + image_count(val_datasets or [], "val")
        predict = graph_predictor(raw, card, images)
        card["accuracy"] = accuracy_on(predict, eval_datasets, split)
        card.pop("accuracy_val", None)
        if val_datasets:
            card["accuracy_val"] = accuracy_on(predict, val_datasets, "val")
        card["date_measured"] = datetime.now(UTC).isoformat(timespec="seconds")
    elif version is not None:
        raise ValueError("a regraphed model must be measured again: give eval data sets")
    elif card.get("name") != name:
        card |= {"name": name, "renamed_from": card.get("name")}
    if notes is not None:
        card["notes"] = notes
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"{name}.onnx"
    path.write_bytes(with_card(raw, card))
    (out_dir / f"{name}.json").write_text(json.dumps(card, indent=1) + "\n")
    return path, card
