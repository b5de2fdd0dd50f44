"""Export a training checkpoint to ONNX with its model card (SPEC section 8, DESIGN "flow").

The graph takes `image` float32 [N, 3, H, W], RGB in [0, 1] (dynamic N; the normalisation is
inside) and returns `probabilities` float32 [N, 9] (softmax); the keypoint networks also take
`pixel_aspect` float32 [N] (an input with the default [1], an overridable initializer: a
caller that feeds only `image` gets square pixels) and return `corners` float32 [N, 4, 2],
the object's image corners in pixels of the input, in the order (-X,-Y), (+X,-Y), (+X,+Y),
(-X,+Y) of the object frame. The model card (JSON) is stored in the ONNX `metadata_props`
under `model_card` and written next to it as `<name>.json`.
"""

from __future__ import annotations

import io
import json
import warnings
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from service.model import CORNERS, PIXEL_ASPECT, PROBABILITIES
from service.regions import NUM_CLASSES, class_descriptions, region_of_class
from train import REPO_ROOT

OPSET = 17
#: What the card says of each architecture (train.network.model.build_network).
ARCHITECTURES = {
    "spec": "spec: the SPEC section 8 network (tanh, L2 pooling), batch norm folded away",
    "convnet": "convnet: train/network/convnet.py (ReLU, batch norm, max pooling, 3x4 head)",
    "keypoint": "keypoint: train/network/keypoint.py (U-Net corner heat maps, corners aligned "
    "to the checker pattern, class from the corners' pose with a prior camera and the squares' "
    "colour parity)",
    "keypoint-s2": "keypoint-s2: train/network/keypoint.py with corner heat maps at 80x60 "
    "(stride 2), corners aligned to the checker pattern (train/network/align.py)",
}
INPUT_NAME = "image"


def onnx_bytes(net: Any) -> bytes:
    """Serialise a pose network (eval mode) to ONNX bytes, dynamic batch: output
    `probabilities` (softmax); the keypoint networks also take `pixel_aspect` (default 1)
    and output `corners`."""
    import onnx
    import torch

    from train.network.model import Probabilities, takes_pixel_aspect

    w, h = net.size
    wrapper = Probabilities(net).eval()
    aspect = takes_pixel_aspect(net)
    inputs = [INPUT_NAME, PIXEL_ASPECT] if aspect else [INPUT_NAME]
    outputs = [PROBABILITIES, CORNERS] if aspect else [PROBABILITIES]
    example = (torch.rand(2, 3, h, w), torch.ones(2)) if aspect else (torch.rand(2, 3, h, w),)
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        torch.onnx.export(
            wrapper,
            example,
            buf,
            dynamo=False,
            input_names=inputs,
            output_names=outputs,
            # the aspect's own batch dimension: its default [1] broadcasts over any N
            dynamic_axes={name: {0: "N"} for name in [INPUT_NAME, *outputs]}
            | ({PIXEL_ASPECT: {0: "N_aspect"}} if aspect else {}),
            opset_version=OPSET,
        )
    if not aspect:
        return buf.getvalue()
    model = onnx.load_from_string(buf.getvalue())
    default = onnx.numpy_helper.from_array(np.ones(1, np.float32), PIXEL_ASPECT)
    model.graph.initializer.append(default)  # a graph input with a default: overridable
    return model.SerializeToString()


def profile_card(profile: dict[str, Any]) -> dict[str, Any]:
    """The object profile part of the card from a data set manifest's profile (+ its file).

    Adds the camera box and roll range from the profile definition when it can be loaded;
    `texture` is given relative to the repository root when it lies inside it.
    """
    card = dict(profile)
    try:
        from train.profile import load_profile

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


def build_card(
    name: str,
    checkpoint: dict[str, Any],
    accuracy: dict[str, dict[str, Any]],
    version: str,
    notes: str,
) -> dict[str, Any]:
    """The model card dict (see module doc) from a checkpoint written by `train.network.fit`."""
    profile = profile_card(checkpoint.get("profile", {}))
    z_split = float(profile.get("z_split_cm", 60.0))
    descriptions = class_descriptions(z_split)
    keypoint = checkpoint.get("arch", "spec").startswith("keypoint")
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
        "architecture": ARCHITECTURES[checkpoint.get("arch", "spec")],
        "input": list(checkpoint["size"]),
        "input_format": "image: float32 [N, 3, H, W], RGB, values in [0, 1] (portraits turned "
        "a quarter clockwise, resize with area)"
        + (
            "; pixel_aspect: float32 [N], default 1, the height over the width of an input "
            "pixel in the scene (4/3 for a 16:9 photo resized to the input)"
            if keypoint
            else ""
        ),
        "output": "probabilities: float32 [N, 9] (softmax), index = class id"
        + (
            "; corners: float32 [N, 4, 2], the object's corners (u, v) in input pixels, "
            "order (-X,-Y), (+X,-Y), (+X,+Y), (-X,+Y)"
            if keypoint
            else ""
        ),
        "classes": [
            {"id": k, "label": region_of_class(k)["label"], "description": descriptions[k]}
            for k in range(NUM_CLASSES)
        ],
        "profile": profile,
        "training": training,
        "accuracy": accuracy,
        "notes": notes,
    }


def with_card(model_bytes: bytes, card: dict[str, Any]) -> bytes:
    """ONNX bytes with `model_card` = card JSON set in metadata_props."""
    import onnx

    model = onnx.load_from_string(model_bytes)
    del model.metadata_props[:]
    entry = model.metadata_props.add()
    entry.key, entry.value = "model_card", json.dumps(card)
    model.producer_name = "planar-pose"
    return model.SerializeToString()


def accuracy_on(predict: Any, datasets: list[Path], split: str) -> dict[str, dict[str, Any]]:
    """{data set folder name: {accuracy, class0_accuracy, count, split, by_margin}} of a
    predictor (`by_margin`: `train.network.evaluate.margin_breakdown`)."""
    from train.dataset import load_dataset
    from train.network.evaluate import compute_metrics, predict_all

    out: dict[str, dict[str, Any]] = {}
    for path in datasets:
        data = load_dataset(path, split=None if split == "all" else split)
        if len(data.labels) == 0:
            raise ValueError(f"{path} has no images in split {split!r}")
        probs, ms = predict_all(predict, data.images, data.pixel_aspect())
        predicted = probs.argmax(axis=1)
        m = compute_metrics(data.labels, predicted, ms, data.boundary_margin_cm())
        out[path.name] = {
            "split": split,
            "count": m["count"],
            "accuracy": round(m["accuracy"], 4),
            "class0_accuracy": m["per_class_accuracy"][0],
            "by_margin": m["by_margin"],
        }
        sources = data.column("source") if data.rows and "source" in data.rows[0] else []
        if sources:  # a real corpus set: accuracy per source (camera) too
            hit = predicted == data.labels
            out[path.name]["by_source"] = {
                s: {"count": int(sum(x == s for x in sources)),
                    "accuracy": round(float(np.mean(hit[[x == s for x in sources]])), 4)}
                for s in sorted(set(sources))
            }  # fmt: skip
    return out


def _graph_predictor(raw: bytes, size: tuple[int, int]) -> Any:
    """A `train.network.evaluate.Predictor` on ONNX bytes (onnxruntime), the pixel aspect
    fed when the graph takes it."""
    import onnxruntime as ort

    from train.network.evaluate import network_batch

    options = ort.SessionOptions()
    options.log_severity_level = 3  # not the warning about the overridable `pixel_aspect`
    session = ort.InferenceSession(raw, options, providers=["CPUExecutionProvider"])
    aspect = any(i.name == PIXEL_ASPECT for i in session.get_overridable_initializers())

    def predict(images: np.ndarray, pixel_aspect: np.ndarray) -> np.ndarray:
        feeds = {INPUT_NAME: network_batch(images, size)}
        if aspect:
            feeds[PIXEL_ASPECT] = np.asarray(pixel_aspect, np.float32)
        return session.run([PROBABILITIES], feeds)[0]

    return predict


def export(
    checkpoint_path: Path,
    name: str,
    out_dir: Path,
    eval_datasets: list[Path] | None = None,
    split: str = "test",
    version: str = "1.0.0",
    notes: str = "",
) -> tuple[Path, dict[str, Any]]:
    """Write out_dir/<name>.onnx and out_dir/<name>.json -> (onnx path, card).

    Accuracy on `eval_datasets` is measured with onnxruntime on the exported graph itself.
    """
    from train.network.fit import load_network
    from train.network.model import export_form

    trained, checkpoint = load_network(checkpoint_path)
    net = export_form(trained)
    raw = onnx_bytes(net)
    predict = _graph_predictor(raw, net.size)
    accuracy = accuracy_on(predict, eval_datasets, split) if eval_datasets else {}
    card = build_card(name, checkpoint, accuracy, version, notes)
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
) -> tuple[Path, dict[str, Any]]:
    """Measure a shipped ONNX model again on `eval_datasets` and write it with its card's
    accuracy replaced (training provenance unchanged) as out_dir/<name>.onnx + .json."""
    import onnx

    model = onnx.load(str(onnx_path))
    cards = [p.value for p in model.metadata_props if p.key == "model_card"]
    if not cards:
        raise ValueError(f"{onnx_path} has no model card in its metadata")
    card = json.loads(cards[0])
    raw = onnx_path.read_bytes()
    predict = _graph_predictor(raw, (int(card["input"][0]), int(card["input"][1])))
    card |= {"name": name, "accuracy": accuracy_on(predict, eval_datasets, split)}
    card["date_measured"] = datetime.now(UTC).isoformat(timespec="seconds")
    if notes is not None:
        card["notes"] = notes
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"{name}.onnx"
    path.write_bytes(with_card(raw, card))
    (out_dir / f"{name}.json").write_text(json.dumps(card, indent=1) + "\n")
    return path, card
