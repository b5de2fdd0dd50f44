"""The comparison report: CNN (ONNX) vs the feature baseline, and whole / sliding / proposals.

Everything is measured in one run on one machine, so times compare as ratios:

* per data set (size, blur, synthetic or real): accuracy of each ONNX model whose input size
  matches the data set (`train.network.evaluate.onnx_predictor` + `evaluate_predictor`: the
  service's preprocessing, batches of 64) and of the feature baseline
  (`train.compare.baseline`, tuned on the data set's val split), ms per image of both and
  their ratio;
* on real data sets: accuracy per blur level, models marked as fine-tuned on real photos or
  not (from their model card);
* detection variants (SPEC section 9) through the service's own `service.predictor.Predictor`
  (image bytes in, like an HTTP call): whole image, sliding windows, and object proposals
  (`service.proposals.propose_boxes` as the predictor's box generator) on the service's
  working copy and on a 4x larger one.

Outputs: the Markdown report (default docs/comparison.md), and next to it a folder with
metrics.json (the `planar-pose evaluate` layout, via `train.network.report.write_report`), the
per-cell report and the PNG plots.
"""

from __future__ import annotations

import json
import os
import platform
import time
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from tqdm import tqdm

from train import REPO_ROOT
from train.compare.baseline import (
    BaselineConfig,
    FeatureBaseline,
    dataset_cameras,
    evaluate_baseline,
)
from train.compare.baseline import tune as tune_baseline
from train.network.evaluate import compute_metrics, evaluate_predictor, onnx_predictor

#: Proposals per image in the objectness mode; about the sliding window count at 1.5x.
PROPOSALS_MAX = 20
#: Working copy scales (network inputs per largest window) for the objectness mode.
PROPOSAL_RESOLUTIONS = (1.5, 4.0)


@dataclass
class CompareConfig:
    """What `run_comparison` measures (see the module docstring)."""

    models: list[Path]
    datasets: list[Path]
    markdown: Path = Path("docs/comparison.md")
    features: str = "sift"
    split: str = "test"
    photos: Path | None = None
    detection_datasets: list[Path] = field(default_factory=list)
    limit: int = 0
    tune: bool = True


@dataclass
class Split:
    """Images RGB uint8 [N, H, W, 3], labels int [N] and file names of one split."""

    images: np.ndarray
    labels: np.ndarray
    files: list[str]


def load_split(folder: Path, split: str, limit: int = 0) -> Split:
    """One split ("all" for every image) of a data set via `train.dataset.load_dataset`,
    the first `limit` images if limit > 0 (the data set's own order)."""
    from train.dataset import load_dataset

    data = load_dataset(folder, split=None if split == "all" else split)
    n = len(data.labels) if limit <= 0 else min(limit, len(data.labels))
    files = data.column("file")[:n]
    return Split(np.asarray(data.images[:n]), np.asarray(data.labels[:n], np.int64), files)


def manifest_of(folder: Path) -> dict[str, Any]:
    """The data set's manifest.json ({} if it has none)."""
    path = folder / "manifest.json"
    return json.loads(path.read_text()) if path.is_file() else {}


def describe(folder: Path, images: np.ndarray) -> dict[str, Any]:
    """Object, kind (real / C / noC), size (W, H) and blur of a data set, from its manifest."""
    m = manifest_of(folder)
    kind = "real" if m.get("real") else str(m.get("variant", "synthetic"))
    profile = m.get("profile")
    return {
        "object": str(profile.get("name", "?") if isinstance(profile, dict) else profile),
        "kind": kind,
        "size": (int(images.shape[2]), int(images.shape[1])),
        "blur": m.get("blur", "?"),
        "real": bool(m.get("real")),
    }


def _profile_of(folder: Path, override: str | None) -> Any:
    from train.profile import load_profile

    if override:
        return load_profile(override)
    entry = manifest_of(folder).get("profile")
    name = entry.get("name") if isinstance(entry, dict) else entry
    try:
        return load_profile(name or "chessboard")
    except ValueError:
        # A profile kept outside train/assets/profiles: its folder holds the recorded texture.
        texture = entry.get("texture") if isinstance(entry, dict) else None
        if not texture:
            raise
        path = Path(texture)
        return load_profile((path if path.is_absolute() else REPO_ROOT / path).parent)


def make_baseline(folder: Path, config: BaselineConfig, profile: str | None) -> FeatureBaseline:
    """The baseline for a data set's object profile (its manifest, or `profile`)."""
    prof = _profile_of(folder, profile)
    z_split = float(prof.geometry.z_split_cm)
    return FeatureBaseline(
        prof.texture_rgb(), float(prof.width_cm), float(prof.height_cm), z_split, config
    )


def run_baseline_on(
    folder: Path,
    config: BaselineConfig,
    split: str,
    tune: bool,
    profile: str | None = None,
    limit: int = 0,
    verbose: bool = False,
) -> tuple[dict, dict[str, Any]]:
    """Baseline metrics on one split of a data set, thresholds tuned on its val split first
    (when `tune` and the set has a val split). Returns (metrics, {failures, tuning})."""
    baseline = make_baseline(folder, config, profile)
    info: dict[str, Any] = {"tuning": None}
    if tune and split != "val":
        val = load_split(folder, "val", limit)
        if len(val.labels):
            size = (val.images.shape[2], val.images.shape[1])
            cams = dataset_cameras(folder, val.files, size)
            with tqdm(
                total=len(val.labels), desc=f"tune on {folder.name}/val", disable=not verbose
            ) as bar:
                baseline, info["tuning"] = tune_baseline(
                    baseline, val.images, val.labels, cams, bar.update
                )
    data = load_split(folder, split, limit)
    if not len(data.labels):
        raise ValueError(f"{folder} has no images in split {split!r}")
    cams = dataset_cameras(folder, data.files, (data.images.shape[2], data.images.shape[1]))
    with tqdm(
        total=len(data.labels), desc=f"baseline on {folder.name}", disable=not verbose
    ) as bar:
        metrics, info["failures"] = evaluate_baseline(
            baseline, data.images, data.labels, cams, bar.update
        )
    return metrics, info


def same_object(card: dict, folder: Path) -> bool:
    """False when the model card and the data set name different object profiles."""
    model_profile = card.get("profile", {})
    data_profile = manifest_of(folder).get("profile", {})
    a = model_profile.get("name") if isinstance(model_profile, dict) else None
    b = data_profile.get("name") if isinstance(data_profile, dict) else None
    return a is None or b is None or a == b


def finetuned_on_real(card: dict) -> bool | None:
    """Whether a model card lists real photographs among its training data (None: unknown)."""
    data = card.get("training", {}).get("data")
    if not isinstance(data, list):
        return None
    return any(isinstance(d, dict) and d.get("real") for d in data)


def photo_set(folder: Path, z_split: float) -> tuple[list[bytes], np.ndarray, list[str]]:
    """Full-size photographs of a labelled folder (labels.csv with file and class or camera
    centre) -> (encoded bytes as stored, classes [N], split of each photo).

    The split is the one `planar-pose realset` gives with its default seed (0): by stereo
    moment, so it matches the real data sets built from the same folder.
    """
    import csv

    from train.geometry import pose_class
    from train.real.realset import moment_of, split_moments

    with (folder / "labels.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    data, labels = [], []
    for row in rows:
        data.append((folder / row["file"]).read_bytes())
        if row.get("class", "") != "":
            labels.append(int(row["class"]))
        else:
            centre = [float(row[k]) for k in ("cam_x", "cam_y", "cam_z")]
            labels.append(int(pose_class(np.array(centre), z_split)))
    splits = split_moments([moment_of(r["file"]) for r in rows], seed=0)
    return data, np.array(labels, np.int64), [splits[moment_of(r["file"])] for r in rows]


def encode_png(images: np.ndarray) -> list[bytes]:
    """RGB uint8 images [N, H, W, 3] -> PNG bytes (lossless), as a client would send them."""
    out = []
    for rgb in images:
        ok, buf = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        if not ok:
            raise ValueError("PNG encoding failed")
        out.append(buf.tobytes())
    return out


def detection_variants(
    model_path: Path,
    images: list[bytes],
    labels: np.ndarray,
    subsets: dict[str, np.ndarray] | None = None,
    chunk: int = 16,
) -> dict[str, dict[str, dict]]:
    """Metrics of whole / sliding / proposals modes through `service.predictor.Predictor`.

    Returns {subset name: {variant: metrics}}; `subsets` maps names to boolean masks [N]
    (default: one subset "all"). Images go in chunks of `chunk` (the service's default
    per-request limit); ms per image is the wall clock of the predictor calls over all images
    (decode + boxes + batched onnxruntime + decision).
    """
    from service.model import PoseModel
    from service.predictor import Predictor
    from service.proposals import propose_boxes
    from service.settings import Settings

    model = PoseModel.load(model_path)
    aspect = model.input_size[0] / model.input_size[1]

    def proposals(work: np.ndarray) -> np.ndarray:
        return propose_boxes(work, aspect, PROPOSALS_MAX)

    variants: dict[str, tuple[Predictor, str]] = {
        "whole": (Predictor(model, Settings()), "whole"),
        "sliding": (Predictor(model, Settings()), "sliding"),
    }
    for res in PROPOSAL_RESOLUTIONS:
        predictor = Predictor(model, Settings(sliding_resolution=res), boxes=proposals)
        variants[f"proposals@{res:g}x"] = (predictor, "sliding")
    subsets = subsets or {"all": np.ones(len(labels), bool)}
    results: dict[str, dict[str, dict]] = {name: {} for name in subsets}
    for variant, (predictor, mode) in variants.items():
        predicted = []
        start = time.perf_counter()
        for i in range(0, len(images), chunk):
            batch = [(None, b) for b in images[i : i + chunk]]
            predicted += [r.class_id for r in predictor.predict(batch, mode).results]
        ms = 1000.0 * (time.perf_counter() - start) / max(len(images), 1)
        for name, mask in subsets.items():
            if mask.any():
                results[name][variant] = compute_metrics(
                    labels[mask], np.array(predicted)[mask], ms
                )
    return {name: res for name, res in results.items() if res}


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.1f}"


def _plot_accuracy(rows: list[dict], names: list[str], path: Path) -> None:
    """Accuracy vs blur level, one panel per (kind, size), one line per model / baseline."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = sorted({(r["object"], r["kind"], r["size"]) for r in rows})
    ncols = min(3, len(panels))
    nrows = -(-len(panels) // ncols)
    fig, axes = plt.subplots(
        nrows, ncols, figsize=(3.6 * ncols, 3.0 * nrows), dpi=80, squeeze=False
    )
    for ax in axes.ravel()[len(panels) :]:
        ax.set_visible(False)
    handles = {}
    for ax, (obj, kind, size) in zip(axes.ravel(), panels, strict=False):
        sub = sorted(
            (r for r in rows if (r["object"], r["kind"], r["size"]) == (obj, kind, size)),
            key=lambda r: str(r["blur"]),
        )
        for k, name in enumerate(names):
            pts = [(r["blur"], 100 * r["acc"][name]) for r in sub if name in r["acc"]]
            if pts:
                xs, ys = [str(b) for b, _ in pts], [a for _, a in pts]
                (handles[name],) = ax.plot(xs, ys, marker="o", color=f"C{k}", label=name)
        ax.set_title(f"{obj}: {kind}, {size[0]}x{size[1]}", fontsize=9)
        ax.set_xlabel("blur level")
        ax.set_ylim(-3, 103)
        ax.grid(alpha=0.3)
    for row in axes:
        row[0].set_ylabel("accuracy %")
    axes[0][0].legend(handles.values(), handles.keys(), fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def _plot_times(rows: list[dict], names: list[str], path: Path) -> None:
    """ms per image of each model and the baseline, per data set (log scale)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(1.5 + 0.6 * len(rows), 3.4), dpi=80)
    width = 0.8 / max(len(names), 1)
    for k, name in enumerate(names):
        xs = [i + k * width for i, r in enumerate(rows) if name in r["ms"]]
        ys = [r["ms"][name] for r in rows if name in r["ms"]]
        ax.bar(xs, ys, width=width, label=name)
    ax.set_xticks(
        [i + 0.4 - width / 2 for i in range(len(rows))],
        [r["name"] for r in rows],
        rotation=60,
        ha="right",
        fontsize=7,
    )
    ax.set_yscale("log")
    ax.set_ylabel("ms / image")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def run_comparison(config: CompareConfig) -> dict[str, Any]:
    """Measure everything (module docstring), write the reports; return a summary with
    `columns`, `rows` (strings for a console table) and `files` written."""
    from train.network.report import write_report

    if not config.models:
        raise ValueError("give at least one ONNX model")
    if not config.datasets:
        raise ValueError("give at least one data set")
    loaded = {}
    for path in config.models:
        predict, size, card = onnx_predictor(path)
        name = card.get("name") if isinstance(card.get("name"), str) else path.stem
        loaded[name] = (path, predict, size, card)
    base_name = f"baseline-{config.features}"
    names = [*loaded, base_name]
    results: dict[str, dict[str, dict]] = {n: {} for n in names}
    rows: list[dict] = []
    for folder in config.datasets:
        data = load_split(folder, config.split, config.limit)
        if not len(data.labels):
            raise ValueError(f"{folder} has no images in split {config.split!r}")
        desc = describe(folder, data.images)
        key = f"{desc['object']}/{folder.name}"
        if any(r["name"] == key for r in rows):
            raise ValueError(f"two data sets would be named {key}")
        row = {"name": key, **desc, "n": len(data.labels), "acc": {}, "ms": {}}
        for name, (_, predict, size, card) in loaded.items():
            if tuple(size) != desc["size"] or not same_object(card, folder):
                continue
            with tqdm(total=len(data.labels), desc=f"{name} on {folder.name}") as bar:
                m = evaluate_predictor(predict, data.images, data.labels, bar.update)
            results[name][key] = m
            row["acc"][name], row["ms"][name] = m["accuracy"], m["ms_per_image"]
        m, info = run_baseline_on(
            folder, BaselineConfig(features=config.features), config.split, config.tune,
            limit=config.limit, verbose=True,
        )  # fmt: skip
        results[base_name][key] = m
        row["acc"][base_name], row["ms"][base_name] = m["accuracy"], m["ms_per_image"]
        row["baseline_info"] = info
        rows.append(row)
        tqdm.write(
            f"{key}: "
            + ", ".join(
                f"{n} {100 * a:.1f} % ({row['ms'][n]:.2f} ms)" for n, a in row["acc"].items()
            )
        )

    detections: dict[str, dict[str, dict[str, dict]]] = {}
    if config.photos is not None or config.detection_datasets:
        prof_folder = config.datasets[0]
        z_split = float(_profile_of(prof_folder, None).geometry.z_split_cm)
        sets: list[tuple[str, list[bytes], np.ndarray, dict[str, np.ndarray]]] = []
        if config.photos is not None:
            photos, labels, splits = photo_set(config.photos, z_split)
            name = f"{config.photos.name} photos"
            subsets = {
                f"{name}, all": np.ones(len(labels), bool),
                f"{name}, test split": np.array(splits) == "test",
            }
            sets.append((name, photos, labels, subsets))
        for folder in config.detection_datasets:
            d = load_split(folder, config.split, config.limit)
            sets.append((folder.name, encode_png(d.images), d.labels, {folder.name: None}))
        for name, (path, _, _, _) in loaded.items():
            detections[name] = {}
            for set_name, images, labels, masks in sets:
                tqdm.write(f"detection variants: {name} on {set_name}")
                full = {k: np.ones(len(labels), bool) if v is None else v for k, v in masks.items()}
                detections[name] |= detection_variants(path, images, labels, full)

    out_dir = config.markdown.with_suffix("")
    details = write_report(
        results,
        out_dir,
        out_dir / "details.md",
        "Comparison details: CNN vs feature baseline",
        [
            f"Split `{config.split}`. Written by `planar-pose compare`; "
            f"summary in {config.markdown.name}."
        ],
        {n: str(p) for n, (p, _, _, _) in loaded.items()}
        | {r["name"]: str(d) for r, d in zip(rows, config.datasets, strict=True)},
    )
    if detections:
        (out_dir / "detection_metrics.json").write_text(json.dumps(detections, indent=1) + "\n")
    plots = out_dir / "plots"
    _plot_accuracy(rows, names, plots / "accuracy_vs_blur.png")
    _plot_times(rows, names, plots / "time_per_image.png")
    text = _markdown(config, loaded, base_name, rows, detections, out_dir, details)
    config.markdown.parent.mkdir(parents=True, exist_ok=True)
    config.markdown.write_text(text)

    table_rows = [
        [r["name"]]
        + [f"{_pct(r['acc'][n])} ({r['ms'][n]:.2f})" if n in r["acc"] else "" for n in names]
        for r in rows
    ]
    return {
        "columns": names,
        "rows": table_rows,
        "files": [str(config.markdown), str(out_dir / "metrics.json"), str(details)],
    }


def _link(path: Path, base: Path) -> str:
    return Path(os.path.relpath(path, base)).as_posix()


def _markdown(
    config: CompareConfig,
    loaded: dict[str, tuple[Path, Any, tuple[int, int], dict]],
    base_name: str,
    rows: list[dict],
    detections: dict[str, dict[str, dict[str, dict]]],
    out_dir: Path,
    details: Path,
) -> str:
    """The report's Markdown (tables from the measured numbers, plots linked)."""
    base = config.markdown.parent
    models = list(loaded)
    cpu = platform.processor() or platform.machine()
    lines = [
        "# CNN vs feature baseline, and the detection variants",
        "",
        f"Written by `planar-pose compare` on {datetime.now(UTC).isoformat(timespec='minutes')} "
        f"({cpu}, {os.cpu_count()} logical CPUs, shared with other jobs: times are indicative, "
        "their ratios measured in the same run are what counts). Split: "
        f"`{config.split}`"
        + (f", at most {config.limit} images per set" if config.limit else "")
        + f". Baseline features: {config.features}.",
        "",
        "Models:",
        "",
    ]
    for name, (path, _, size, card) in loaded.items():
        ft = finetuned_on_real(card)
        tag = {True: "trained or fine-tuned on real photos", False: "synthetic data only",
               None: "training data not in its card"}[ft]  # fmt: skip
        lines.append(f"* `{name}` ({path}, input {size[0]}x{size[1]}): {tag}.")
    lines += [
        "",
        "## Accuracy and time per data set",
        "",
        "Accuracy %, and ms per image (CNN: service preprocessing + onnxruntime, batches of 64; "
        "baseline: feature detection + matching + RANSAC + PnP, one image at a time). A model "
        "is run on the data sets of its input size and its object only.",
        "",
    ]
    header = ["data set", "object", "kind", "size", "blur", "n"]
    header += [f"{m} %" for m in models] + [f"{base_name} %"]
    header += [f"{m} ms" for m in models] + [f"{base_name} ms", "baseline / CNN time"]
    lines += ["| " + " | ".join(header) + " |", "|---" * len(header) + "|"]
    ratios = []
    for r in rows:
        cnn_ms = [r["ms"][m] for m in models if m in r["ms"]]
        ratio = r["ms"][base_name] / min(cnn_ms) if cnn_ms else None
        if ratio is not None:
            ratios.append(ratio)
        cells = [
            r["name"],
            r["object"],
            r["kind"],
            f"{r['size'][0]}x{r['size'][1]}",
            str(r["blur"]),
            str(r["n"]),
        ]
        cells += [_pct(r["acc"].get(m)) for m in models] + [_pct(r["acc"][base_name])]
        cells += [f"{r['ms'][m]:.2f}" if m in r["ms"] else "-" for m in models]
        cells += [f"{r['ms'][base_name]:.1f}", "-" if ratio is None else f"{ratio:.1f}x"]
        lines.append("| " + " | ".join(cells) + " |")
    lines += [
        "",
        f"![accuracy vs blur]({_link(out_dir / 'plots' / 'accuracy_vs_blur.png', base)})",
        "",
        f"![time per image]({_link(out_dir / 'plots' / 'time_per_image.png', base)})",
        "",
    ]
    if ratios:
        lines += [
            f"The baseline took {np.median(ratios):.1f}x the CNN's time per image (median over "
            f"data sets; range {min(ratios):.1f}x-{max(ratios):.1f}x).",
            "",
        ]
    lines += [
        "### The baseline",
        "",
        "Per object: mean baseline accuracy, share of images where no pose was found (answered "
        "class 0), and the most frequent reason.",
        "",
        "| object | data sets | mean accuracy % | no pose % | main reason |",
        "|---|---|---|---|---|",
    ]
    for obj in dict.fromkeys(r["object"] for r in rows):
        mine = [r for r in rows if r["object"] == obj]
        reasons: dict[str, int] = {}
        for r in mine:
            for k, v in r["baseline_info"]["failures"].items():
                reasons[k] = reasons.get(k, 0) + v
        n = sum(r["n"] for r in mine)
        main = max(reasons, key=lambda k: reasons[k]) if reasons else "-"
        acc = float(np.mean([r["acc"][base_name] for r in mine]))
        lines.append(
            f"| {obj} | {len(mine)} | {_pct(acc)} | {_pct(sum(reasons.values()) / n)} | {main} |"
        )
    lines += [
        "",
        "Per data set, the thresholds chosen on its validation split and why images got no pose:",
        "",
    ]
    for r in rows:
        info = r["baseline_info"]
        t = info.get("tuning")
        chosen = (
            f"ratio {t['chosen']['ratio']}, RANSAC {t['chosen']['ransac_px']} px "
            f"(val {_pct(t['val_accuracy'])} %)"
            if t
            else "default thresholds (no tuning)"
        )
        fails = ", ".join(f"{k}: {v}" for k, v in info["failures"].items()) or "none"
        lines.append(f"* `{r['name']}`: {chosen}; no pose: {fails}.")
    lines.append("")

    real_rows = [r for r in rows if r["real"]]
    lines += ["## Real photographs per blur level", ""]
    if real_rows:
        cols = models + [base_name]
        lines += ["| size | blur | n | " + " | ".join(f"{c} %" for c in cols) + " |"]
        lines += ["|---" * (3 + len(cols)) + "|"]
        for r in sorted(real_rows, key=lambda r: (r["size"], str(r["blur"]))):
            cells = [f"{r['size'][0]}x{r['size'][1]}", str(r["blur"]), str(r["n"])]
            lines.append("| " + " | ".join(cells + [_pct(r["acc"].get(c)) for c in cols]) + " |")
        tags = {m: finetuned_on_real(loaded[m][3]) for m in models}
        if not any(t is False for t in tags.values()):
            lines += [
                "",
                "No model trained on synthetic data only (before fine-tuning) was given, so "
                "the effect of fine-tuning is not measured here.",
            ]
    else:
        lines.append("No real data set was given.")
    lines.append("")

    lines += ["## Detection variants: whole image, sliding windows, object proposals", ""]
    if detections:
        lines += [
            "Through the service's `Predictor` (image bytes in). `sliding`: the service's window "
            "grid on its working copy (largest window = 1.5 network inputs); `proposals@Sx`: "
            f"`service.proposals.propose_boxes` (at most {PROPOSALS_MAX} boxes) as the box "
            "generator on a working copy where the largest window is S network inputs. "
            "Accuracy %, ms per image. A model trained or fine-tuned on real photos has seen "
            "the photos outside the test split (same split as `planar-pose realset`, seed 0): "
            "only the test split rows are a fair measure for it.",
            "",
        ]
        variants = list(next(iter(next(iter(detections.values())).values())))
        lines += ["| model | images | n | " + " | ".join(variants) + " |"]
        lines += ["|---" * (3 + len(variants)) + "|"]
        for model, sets in detections.items():
            for set_name, res in sets.items():
                n = next(iter(res.values()))["count"]
                cells = [
                    f"{_pct(res[v]['accuracy'])} ({res[v]['ms_per_image']:.1f} ms)"
                    for v in variants
                ]
                lines.append(f"| {model} | {set_name} | {n} | " + " | ".join(cells) + " |")
    else:
        lines.append("Not measured in this run (give --photos and/or --detection-dataset).")
    lines += [
        "",
        f"Per-class metrics, confusion matrices and plots of every cell: [{details.name}]"
        f"({_link(details, base)}); numbers: "
        f"[metrics.json]({_link(out_dir / 'metrics.json', base)}).",
        "",
    ]
    return "\n".join(lines)
