"""Evaluation reports (SPEC section 10): metrics.json, a summary page, and per-cell details
with matplotlib plots in the output folder.

`results` everywhere is {model name: {data set name: metrics}}, where metrics is the dict of
`train.network.evaluate.compute_metrics`. One model is a grid with one row; the thesis-style
table has models as rows and data sets as columns.
"""

from __future__ import annotations

import json
import re
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from service.core.regions import NUM_CLASSES, region_of_class
from train.markdown import link, machine, pct, pct_cell, table

CLASS_LABELS = [region_of_class(k)["label"] for k in range(NUM_CLASSES)]


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_") or "x"


def plot_cell(metrics: dict[str, Any], title: str, path: Path) -> None:
    """One PNG: the confusion heat map (rows = truth) and per-class accuracy/precision/F1 bars."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cm = np.asarray(metrics["confusion"], dtype=float)
    rows = cm.sum(axis=1, keepdims=True)
    share = np.divide(cm, rows, out=np.zeros_like(cm), where=rows > 0)
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4), dpi=72)
    ax1.imshow(share, cmap="Blues", vmin=0, vmax=1)
    for i in range(NUM_CLASSES):
        for j in range(NUM_CLASSES):
            if cm[i, j]:
                colour = "white" if share[i, j] > 0.5 else "black"
                ax1.text(j, i, f"{int(cm[i, j])}", ha="center", va="center", fontsize=7, c=colour)
    ax1.set_xticks(range(NUM_CLASSES))
    ax1.set_yticks(range(NUM_CLASSES))
    ax1.set_xlabel("predicted class")
    ax1.set_ylabel("true class")
    ax1.set_title("confusion (counts; colour = row share)", fontsize=9)
    x = np.arange(NUM_CLASSES)
    for offset, key in ((-0.27, "per_class_accuracy"), (0.0, "precision"), (0.27, "f1")):
        values = [np.nan if v is None else 100 * v for v in metrics[key]]
        ax2.bar(x + offset, values, width=0.27, label=key.replace("_", " "))
    ax2.set_xticks(x)
    ax2.set_ylim(0, 100)
    ax2.set_xlabel("class")
    ax2.set_ylabel("%")
    ax2.legend(fontsize=7, loc="lower right")
    ax2.set_title("per class", fontsize=9)
    fig.suptitle(f"{title}: accuracy {pct_cell(metrics['accuracy'])} %", fontsize=10)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_grid(results: dict[str, dict[str, dict[str, Any]]], path: Path) -> None:
    """Heat map of global accuracy (%), models as rows, data sets as columns."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    models = list(results)
    datasets = list(dict.fromkeys(d for m in models for d in results[m]))
    acc = np.full((len(models), len(datasets)), np.nan)
    for i, m in enumerate(models):
        for j, d in enumerate(datasets):
            if d in results[m]:
                acc[i, j] = 100 * results[m][d]["accuracy"]
    fig, ax = plt.subplots(figsize=(1.2 + 0.7 * len(datasets), 1.2 + 0.45 * len(models)), dpi=72)
    ax.imshow(acc, cmap="RdYlGn", vmin=50, vmax=100, aspect="auto")
    for i in range(len(models)):
        for j in range(len(datasets)):
            if not np.isnan(acc[i, j]):
                ax.text(j, i, f"{acc[i, j]:.1f}", ha="center", va="center", fontsize=7)
    ax.set_xticks(range(len(datasets)), datasets, rotation=60, ha="right", fontsize=7)
    ax.set_yticks(range(len(models)), models, fontsize=7)
    ax.set_title("accuracy (%)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def grid_table(results: dict[str, dict[str, dict[str, Any]]], key: str = "accuracy") -> list[str]:
    """Markdown table of one metric, models as rows, data sets as columns.

    "ms_per_image" is shown in ms; "accuracy" and the `regions` keys ("side", ...) in %.
    """

    def cell(metrics: dict[str, Any]) -> str:
        if key == "ms_per_image":
            return f"{metrics[key]:.2f}"
        return pct_cell(metrics[key] if key in metrics else metrics.get("regions", {}).get(key))

    datasets = list(dict.fromkeys(d for m in results for d in results[m]))
    body = [
        [model, *("" if d not in row else cell(row[d]) for d in datasets)]
        for model, row in results.items()
    ]
    return table(["model", *datasets], body)


def _regions_line(metrics: dict[str, Any]) -> list[str]:
    """What the predictions on images showing the object get right (empty if there are none)."""
    regions = metrics.get("regions") or {}
    if regions.get("detected") is None:
        return []
    return [
        f"Images showing the object: detected {pct_cell(regions['detected'])} %, x/y side "
        f"right {pct_cell(regions['side'])} %, near/far right {pct_cell(regions['distance'])} "
        f"%, opposite side (a half turn) {pct_cell(regions['opposite_side'])} %.",
        "",
    ]


def band_label(band: dict[str, Any]) -> str:
    """'2-5 cm' or '>= 10 cm' for a `by_margin` band."""
    if band["hi_cm"] is None:
        return f">= {band['lo_cm']:g} cm"
    return f"{band['lo_cm']:g}-{band['hi_cm']:g} cm"


def margin_line(bands: list[dict[str, Any]] | None) -> str:
    """`by_margin` bands as one sentence ('' without them)."""
    if not bands:
        return ""
    parts = [f"{band_label(b)}: {pct_cell(b['accuracy'])} % of {b['count']}" for b in bands]
    return (
        "Right class by the camera centre's distance from the nearest region boundary: "
        + ", ".join(parts)
        + "."
    )


def framing_line(framing: dict[str, Any] | None) -> str:
    """A `by_framing` breakdown as one sentence ('' without it or without cut boards)."""
    if not framing or not framing["cut"]["count"]:
        return ""
    whole, cut = framing["whole"], framing["cut"]
    return (
        f"Boards the frame cuts (a labelled corner outside the image): "
        f"{pct_cell(cut['accuracy'])} % of {cut['count']}; whole in view: "
        f"{pct_cell(whole['accuracy'])} % of {whole['count']}."
    )


SOURCE_HEADER = [
    "source",
    "photos",
    "accuracy",
    "detected",
    "near/far right",
    "x/y side right",
    "fx (x SPEC camera)",
]


def source_table(sources: dict[str, dict[str, Any]]) -> list[str]:
    """Markdown rows of a `by_source` breakdown (`train.network.evaluate.source_breakdown`;
    "-" where it has no such figure: cards written before it hold the accuracy only)."""
    rows = []
    for name, v in sources.items():
        focal = v.get("focal_scale")
        rows.append(
            [
                f"`{name}`",
                v["count"],
                pct(v["accuracy"]),
                *(pct(v.get(k), missing="-") for k in ("detected", "distance", "side")),
                "-" if focal is None else f"{focal:.2f}",
            ]
        )
    return table(SOURCE_HEADER, rows)


def cell_section(model: str, dataset: str, metrics: dict[str, Any], image: str) -> list[str]:
    """Markdown details of one (model, data set): summary, per-class table, plot."""
    lines = [
        f"## {model} on {dataset}",
        "",
        f"{metrics['count']} images, accuracy {pct_cell(metrics['accuracy'])} %, class 0 "
        f"accuracy {pct_cell(metrics['per_class_accuracy'][0])} %, "
        f"{metrics['ms_per_image']:.2f} ms / image.",
        "",
        *_regions_line(metrics),
        *([line, ""] if (line := margin_line(metrics.get("by_margin"))) else []),
        *([line, ""] if (line := framing_line(metrics.get("by_framing"))) else []),
        *(["By source:", "", *source_table(s), ""] if (s := metrics.get("by_source")) else []),
    ]
    keys = ("per_class_accuracy", "precision", "recall", "f1")
    body = [
        [k, CLASS_LABELS[k], *(pct_cell(metrics[key][k]) for key in keys)]
        for k in range(NUM_CLASSES)
    ]
    header = ["class", "region", "accuracy %", "precision %", "recall %", "F1 %"]
    return lines + table(header, body) + ["", f"![{model} on {dataset}]({image})", ""]


#: The folder of `write_report`'s out_dir that holds the per-cell details and their plots.
DETAILS_DIR = "details"


def write_metrics(
    results: dict[str, dict[str, dict[str, Any]]],
    out_dir: Path,
    title: str = "Evaluation",
    sources: dict[str, str] | None = None,
) -> Path:
    """Write out_dir/metrics.json: the results with the title, when (UTC) and on which
    machine they were measured, the class labels and `sources` (model / data set paths)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    document = {
        "title": title,
        "date": datetime.now(UTC).isoformat(timespec="seconds"),
        "machine": machine(),
        "classes": CLASS_LABELS,
        "sources": sources or {},
        "results": results,
    }
    path = out_dir / "metrics.json"
    path.write_text(json.dumps(document, indent=1) + "\n")
    return path


def write_details(
    results: dict[str, dict[str, dict[str, Any]]],
    folder: Path,
    title: str = "Evaluation",
    notes: list[str] | None = None,
) -> Path:
    """Write folder/details.md, one section per (model, data set) (`cell_section`), and
    one plot per cell in folder/plots; return the Markdown path."""
    plots = folder / "plots"
    plots.mkdir(parents=True, exist_ok=True)
    path = folder / "details.md"
    lines = [f"# {title}: details", ""]
    for note in notes or []:
        lines += [note, ""]
    for model, row in results.items():
        for dataset, metrics in row.items():
            png = plots / f"{_slug(model)}__{_slug(dataset)}.png"
            plot_cell(metrics, f"{model} on {dataset}", png)
            lines += cell_section(model, dataset, metrics, link(png, folder))
    path.write_text("\n".join(lines) + "\n")
    return path


def write_report(
    results: dict[str, dict[str, dict[str, Any]]],
    out_dir: Path,
    markdown: Path | None = None,
    title: str = "Evaluation",
    notes: list[str] | None = None,
    sources: dict[str, str] | None = None,
) -> Path:
    """Write out_dir/metrics.json (`write_metrics`), the summary page `markdown` and the
    per-cell details in out_dir/details (`write_details`); return the summary's path.

    The summary holds the grid tables (accuracy, x/y side, near/far, time) and the accuracy
    grid's plot (out_dir/plots/grid.png) when there is more than one cell. `markdown`
    defaults to out_dir/report.md (links are made relative to it); `notes` are paragraphs
    placed under the title (and the details' title); `sources` maps model / data set names
    to paths.
    """
    metrics_json = write_metrics(results, out_dir, title, sources)
    details = write_details(results, out_dir / DETAILS_DIR, title, notes)
    markdown = markdown or out_dir / "report.md"
    markdown.parent.mkdir(parents=True, exist_ok=True)
    lines = [f"# {title}", ""]
    for note in notes or []:
        lines += [note, ""]
    lines += ["## Accuracy (%), models x data sets", ""] + grid_table(results) + [""]
    if sum(len(row) for row in results.values()) > 1:
        grid_png = out_dir / "plots" / "grid.png"
        grid_png.parent.mkdir(exist_ok=True)
        plot_grid(results, grid_png)
        lines += [f"![accuracy grid]({link(grid_png, markdown.parent)})", ""]
    for key, heading in (
        ("side", "Right x/y side (%), distance ignored"),
        ("distance", "Right near/far (%), side ignored"),
        ("detected", "Object detected (%)"),
    ):
        lines += [f"## {heading}, on the images that show the object", ""]
        lines += [*grid_table(results, key), ""]
    lines += ["## Time per image (ms, preprocessing + inference, batch 64)", ""]
    lines += [*grid_table(results, "ms_per_image"), ""]
    lines += [
        "## Details",
        "",
        f"Every number above is in [metrics.json]({link(metrics_json, markdown.parent)}). Per "
        "model and data set (per-class accuracy, precision, recall and F1, the confusion "
        "matrix, the breakdowns by source, by the camera's distance from a region boundary "
        f"and by framing, one plot each), the same command writes `{details.as_posix()}` "
        "next to it.",
    ]
    markdown.write_text("\n".join(lines) + "\n")
    return markdown
