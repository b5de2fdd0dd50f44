"""The comparison's Markdown (docs/comparison.md): one writer per section, tables through
`train.markdown.table`, percentages through `train.markdown.pct`.

A *row* is one data set: `name`, `object`, `kind`, `size` (W, H), `blur`, `real`, `n`,
`acc` / `ms` {method: accuracy in [0, 1] / ms per image}, `margin` {method: `by_margin` bands
of `train.network.evaluate.margin_breakdown`}, `info` {peer: {failures, tuning}} and
`reference` {peer: (what was measured, metrics) on the stored photos, or None}.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from train.compare.detection import PROPOSALS_MAX
from train.compare.sets import finetuned_on_real
from train.markdown import link, machine, pct, pct_cell, table
from train.network.report import band_label

#: The peer the chessboard section is about (`train.compare.peers.peer_name("chessboard")`).
CHESSBOARD = "opencv-chessboard"
GIVEN_FX = " + fx"  # name suffix of a model given the detector's focal length (run.py)


@dataclass(frozen=True)
class ReportContext:
    """What every writer may need: the run's settings, the models {name: (path, input size
    (W, H), card)}, the peers' names, the report's folder (`base`), its data folder, whether
    models also answered data sets of other sizes (`resize`) and which models are given the
    detector's focal length (`given_fx`: `<model> + fx`)."""

    split: str
    limit: int
    models: dict[str, tuple[Path, tuple[int, int], dict[str, Any]]]
    peers: list[str]
    base: Path
    out_dir: Path
    resize: bool = False
    given_fx: frozenset[str] = frozenset()


def _ms(value: float | None, digits: int = 2) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def cnn_ms(row: dict[str, Any], models: Sequence[str]) -> float | None:
    """The fastest model's ms per image on a row (None when no model ran on it)."""
    times = [row["ms"][m] for m in models if m in row["ms"]]
    return min(times) if times else None


def time_ratio(row: dict[str, Any], peer: str, models: Sequence[str]) -> float | None:
    """Peer's ms per image over the fastest model's on a row (None if either is missing)."""
    cnn = cnn_ms(row, models)
    return None if cnn is None or peer not in row["ms"] else row["ms"][peer] / cnn


def time_ratios(rows: list[dict[str, Any]], peer: str, models: Sequence[str]) -> list[float]:
    """`time_ratio` of every row where both the peer and a model ran."""
    ratios = (time_ratio(r, peer, models) for r in rows)
    return [x for x in ratios if x is not None]


def header_section(ctx: ReportContext) -> list[str]:
    """Title, when / where it was measured, and the models with their training data."""
    limit = f", at most {ctx.limit} images per set" if ctx.limit else ""
    lines = [
        "# CNN vs the classical peers (chessboard detector, feature baseline), and the "
        "detection variants",
        "",
        f"Written by `planar-pose compare` on {datetime.now(UTC).isoformat(timespec='minutes')} "
        f"on {machine()} (shared with other jobs: times are indicative, their ratios measured "
        f"in the same run are what counts); do not edit by hand. Split: `{ctx.split}`{limit}. "
        f"Peers: {', '.join(ctx.peers)}.",
        "",
        "Models:",
        "",
    ]
    tags = {
        True: "trained or fine-tuned on real photos",
        False: "synthetic data only",
        None: "training data not in its card",
    }
    for name, (path, size, card) in ctx.models.items():
        if name in ctx.given_fx:
            lines.append(
                f"* `{name}`: `{name.removesuffix(GIVEN_FX)}` given each image's focal length "
                "fx, that of the camera the chessboard detector is given (below)."
            )
            continue
        lines.append(
            f"* `{name}` ({path}, input {size[0]}x{size[1]}): {tags[finetuned_on_real(card)]}."
        )
    return lines + [""]


def accuracy_section(ctx: ReportContext, rows: list[dict[str, Any]]) -> list[str]:
    """Accuracy and ms per image of every method per data set, the plots, the time ratios."""
    models, peers = list(ctx.models), ctx.peers
    header = ["data set", "object", "kind", "size", "blur", "n"]
    header += [f"{m} %" for m in [*models, *peers]] + [f"{m} ms" for m in [*models, *peers]]
    header += [f"{p} / CNN time" for p in peers]
    body = []
    for r in rows:
        cells = [
            r["name"],
            r["object"],
            r["kind"],
            f"{r['size'][0]}x{r['size'][1]}",
            str(r["blur"]),
            str(r["n"]),
        ]
        cells += [pct_cell(r["acc"].get(m)) for m in [*models, *peers]]
        cells += [_ms(r["ms"].get(m)) for m in models] + [_ms(r["ms"].get(p), 1) for p in peers]
        row_ratios = [time_ratio(r, p, models) for p in peers]
        body.append(cells + ["-" if x is None else f"{x:.1f}x" for x in row_ratios])
    lines = [
        "## Accuracy and time per data set",
        "",
        "Accuracy %, and ms per image (CNN: service preprocessing + onnxruntime, batches of 64; "
        "peers one image at a time: the feature baseline is feature detection + matching + "
        "RANSAC + PnP, the chessboard detector is 4x cubic enlargement + "
        "`findChessboardCornersSB` (fallback `findChessboardCorners`) + colour parity + IPPE "
        "PnP). "
        + (
            "A model is run on the data sets of its object, those of another size resized to "
            "its input as the service resizes an upload; "
            if ctx.resize
            else "A model is run on the data sets of its input size and its object only, "
        )
        + "the chessboard detector on chessboard data sets only.",
        "",
        *table(header, body),
        "",
        f"![accuracy vs blur]({link(ctx.out_dir / 'plots' / 'accuracy_vs_blur.png', ctx.base)})",
        "",
        f"![time per image]({link(ctx.out_dir / 'plots' / 'time_per_image.png', ctx.base)})",
        "",
    ]
    for peer in peers:
        ratios = time_ratios(rows, peer, models)
        if ratios:
            lines += [
                f"`{peer}` took {np.median(ratios):.1f}x the CNN's time per image (median over "
                f"data sets; range {min(ratios):.1f}x-{max(ratios):.1f}x).",
                "",
            ]
    return lines


def _best_model(group: list[dict[str, Any]], models: Sequence[str]) -> str | None:
    """The model of best mean accuracy over the rows of a group (None: no model ran there)."""
    scores = {
        m: np.mean([r["acc"][m] for r in group if m in r["acc"]])
        for m in models
        if any(m in r["acc"] for r in group)
    }
    return max(scores, key=lambda m: scores[m]) if scores else None


def _blur_list(items: list[tuple[Any, float, float]]) -> str:
    return ", ".join(f"{b} ({pct(a, unit=False)} vs {pct(c, unit=False)} %)" for b, a, c in items)


def verdict(group: list[dict[str, Any]], model: str, peer: str, models: Sequence[str]) -> str:
    """One plain sentence: at which blur levels the network is ahead of the peer and at which
    the peer is, and their time ratio, over the rows of one (kind, size) group."""
    r0 = group[0]
    where = f"At {r0['size'][0]}x{r0['size'][1]}, {r0['kind']}"
    mine = [r for r in group if model in r["acc"] and peer in r["acc"]]
    net = [
        (r["blur"], r["acc"][model], r["acc"][peer])
        for r in mine
        if r["acc"][model] > r["acc"][peer]
    ]
    them = [
        (r["blur"], r["acc"][peer], r["acc"][model])
        for r in mine
        if r["acc"][peer] > r["acc"][model]
    ]
    level = [str(r["blur"]) for r in mine if r["acc"][peer] == r["acc"][model]]
    parts = [
        f"the network (`{model}`) is ahead at blur {_blur_list(net)}"
        if net
        else f"the network (`{model}`) is ahead at no blur level",
        f"the chessboard detector is ahead at blur {_blur_list(them)}"
        if them
        else "the chessboard detector is ahead at no blur level",
    ]
    if level:
        parts.append(f"they are level at blur {', '.join(level)}")
    ratios = time_ratios(mine, peer, [model])
    timing = (
        f" The detector took {min(ratios):.0f}-{max(ratios):.0f}x the network's time per image."
        if ratios
        else ""
    )
    return f"{where}: " + "; ".join(parts) + "." + timing


def _reference_rows(group: list[dict[str, Any]], peer: str, width: int) -> list[list[str]]:
    """Table rows of the peer on the stored photos behind a group's images (once each)."""
    seen, out = set(), []
    for r in group:
        ref = (r.get("reference") or {}).get(peer)
        if ref is None or ref[0] in seen:
            continue
        seen.add(ref[0])
        name, m = ref
        cells = [f"stored photos, no blur ({name})", str(m["count"])]
        cells += ["-"] * width + [pct_cell(m["accuracy"]), "-", _ms(m["ms_per_image"], 1), "-"]
        out.append(cells)
    return out


def chessboard_section(ctx: ReportContext, rows: list[dict[str, Any]]) -> list[str]:
    """The network vs OpenCV's chessboard detector per input size and blur level, with the
    time ratio, the detector on the stored photos for reference, and a verdict per size."""
    lines = ["## The network vs the chessboard detector, per input size and blur level", ""]
    mine = [r for r in rows if CHESSBOARD in r["acc"]]
    if CHESSBOARD not in ctx.peers or not mine:
        return lines + [
            "The chessboard detector was not run (no chessboard data set, or "
            "`--peer chessboard` not given).",
            "",
        ]
    lines += [
        "The detector runs on each data set image (network input size, blurred as the set is) "
        "enlarged 4x (cubic) with the intrinsics scaled accordingly, each image's own camera "
        "(labels.csv, else the source's calibration, else the SPEC camera); no board found = "
        "class 0. Where the data set's stored photographs are on this machine, it also runs on "
        "them as stored (not enlarged, no blur) for reference.",
        "",
    ]
    groups: dict[tuple[Any, ...], list[dict[str, Any]]] = {}
    for r in sorted(mine, key=lambda r: (not r["real"], r["kind"], r["size"], str(r["blur"]))):
        groups.setdefault((r["kind"], r["size"]), []).append(r)
    for (kind, size), group in groups.items():
        models = [m for m in ctx.models if any(m in r["acc"] for r in group)]
        best = _best_model(group, [m for m in models if m not in ctx.given_fx])
        timed = [best] if best is not None else models  # the network the verdict names
        header = ["blur", "n", *(f"{m} %" for m in models), f"{CHESSBOARD} %"]
        header += [f"{best or 'CNN'} ms", f"{CHESSBOARD} ms", "detector / CNN time"]
        body = []
        for r in group:
            ratio = time_ratio(r, CHESSBOARD, timed)
            body.append(
                [
                    str(r["blur"]),
                    str(r["n"]),
                    *(pct_cell(r["acc"].get(m)) for m in models),
                    pct_cell(r["acc"][CHESSBOARD]),
                    _ms(cnn_ms(r, timed)),
                    _ms(r["ms"][CHESSBOARD], 1),
                    "-" if ratio is None else f"{ratio:.0f}x",
                ]
            )
        body += _reference_rows(group, CHESSBOARD, len(models))
        lines += [f"### {kind}, {size[0]}x{size[1]}", "", *table(header, body), ""]
        if best is not None:
            lines += [verdict(group, best, CHESSBOARD, models), ""]
        for given in (m for m in models if m in ctx.given_fx):
            said = verdict(group, given, CHESSBOARD, models)
            lines += [f"Given the detector's focal length, {said[0].lower()}{said[1:]}", ""]
    return lines


def peers_section(ctx: ReportContext, rows: list[dict[str, Any]]) -> list[str]:
    """Per peer and object: mean accuracy, share of no pose and its main reason; per data set
    the thresholds the feature baseline chose on val and why images got no pose."""
    lines = [
        "## The peers",
        "",
        "Per peer and object: mean accuracy, share of images where no pose was found "
        "(answered class 0), and the most frequent reason.",
        "",
    ]
    body = []
    for peer in ctx.peers:
        for obj in dict.fromkeys(r["object"] for r in rows if peer in r["info"]):
            mine = [r for r in rows if r["object"] == obj and peer in r["info"]]
            reasons: dict[str, int] = {}
            for r in mine:
                for k, v in r["info"][peer]["failures"].items():
                    reasons[k] = reasons.get(k, 0) + v
            n = sum(r["n"] for r in mine)
            main = max(reasons, key=lambda k: reasons[k]) if reasons else "-"
            acc = float(np.mean([r["acc"][peer] for r in mine]))
            body.append(
                [peer, obj, len(mine), pct_cell(acc), pct_cell(sum(reasons.values()) / n), main]
            )
    header = ["peer", "object", "data sets", "mean accuracy %", "no pose %", "main reason"]
    lines += [*table(header, body), ""]
    lines += [
        "Per data set and peer, the thresholds chosen on its validation split (feature "
        "baseline) and why images got no pose:",
        "",
    ]
    for r in rows:
        for peer, info in r["info"].items():
            t = info.get("tuning")
            chosen = (
                f"ratio {t['chosen']['ratio']}, RANSAC {t['chosen']['ransac_px']} px "
                f"(val {pct_cell(t['val_accuracy'])} %)"
                if t
                else ("nothing to tune" if peer == CHESSBOARD else "default thresholds (no tuning)")
            )
            fails = ", ".join(f"{k}: {v}" for k, v in info["failures"].items()) or "none"
            lines.append(f"* `{r['name']}`, {peer}: {chosen}; no pose: {fails}.")
    return lines + [""]


def real_blur_section(ctx: ReportContext, rows: list[dict[str, Any]]) -> list[str]:
    """The real data sets per size and blur level, every method; whether fine-tuning shows."""
    lines = ["## Real photographs per blur level", ""]
    real_rows = [r for r in rows if r["real"]]
    if not real_rows:
        return lines + ["No real data set was given.", ""]
    cols = [*ctx.models, *ctx.peers]
    body = [
        [
            r["kind"],
            f"{r['size'][0]}x{r['size'][1]}",
            str(r["blur"]),
            str(r["n"]),
            *(pct_cell(r["acc"].get(c)) for c in cols),
        ]
        for r in sorted(real_rows, key=lambda r: (r["kind"], r["size"], str(r["blur"])))
    ]
    lines += table(["kind", "size", "blur", "n", *(f"{c} %" for c in cols)], body)
    if not any(finetuned_on_real(card) is False for _, _, card in ctx.models.values()):
        lines += [
            "",
            "No model trained on synthetic data only (before fine-tuning) was given, so "
            "the effect of fine-tuning is not measured here.",
        ]
    return lines + [""]


def margin_section(ctx: ReportContext, rows: list[dict[str, Any]]) -> list[str]:
    """Real photographs at blur 0 and 3: accuracy of every method by the camera centre's
    distance from the nearest region boundary."""
    real_rows = [r for r in rows if r["real"] and str(r["blur"]) in ("0", "3") and r["margin"]]
    if not real_rows:
        return []
    lines = [
        "## Real photographs by the camera's distance from a region boundary",
        "",
        "Accuracy on the photos that show the board, by how far the labelled camera centre "
        "is from the nearest region boundary (x = 0, y = 0 or z = z_split in the board's "
        "frame). Near a boundary a class asks for the view direction to a few degrees.",
        "",
    ]
    body, labels = [], []
    for r in sorted(real_rows, key=lambda r: (r["size"], str(r["blur"]))):
        for method, bands in r["margin"].items():
            if bands:
                labels = [f"{band_label(b)} % (n)" for b in bands]
                cells = [f"{pct_cell(b['accuracy'])} ({b['count']})" for b in bands]
                body.append([f"{r['size'][0]}x{r['size'][1]}", str(r["blur"]), method, *cells])
    return lines + table(["size", "blur", "method", *labels], body) + [""]


def detection_section(detections: dict[str, dict[str, dict[str, dict[str, Any]]]]) -> list[str]:
    """Whole image vs sliding windows vs object proposals, per model and image set."""
    lines = ["## Detection variants: whole image, sliding windows, object proposals", ""]
    if not detections:
        return lines + ["Not measured in this run (give --photos and/or --detection-dataset).", ""]
    lines += [
        "Through the service's `Predictor` (image bytes in). `sliding`: the service's window "
        "grid on its working copy (largest window = 1.5 network inputs); `proposals@Sx`: "
        f"`service.pipeline.propose_boxes` (at most {PROPOSALS_MAX} boxes) as the box "
        "generator on a working copy where the largest window is S network inputs. "
        "Accuracy %, ms per image. A model trained or fine-tuned on real photos has seen "
        "the photos outside the test split (same split as `planar-pose realset`, seed 0): "
        "only the test split rows are a fair measure for it.",
        "",
    ]
    variants = list(next(iter(next(iter(detections.values())).values())))
    body = []
    for model, sets in detections.items():
        for set_name, res in sets.items():
            n = next(iter(res.values()))["count"]
            body.append(
                [
                    model,
                    set_name,
                    n,
                    *(
                        f"{pct_cell(res[v]['accuracy'])} ({res[v]['ms_per_image']:.1f} ms)"
                        for v in variants
                    ),
                ]
            )
    return lines + table(["model", "images", "n", *variants], body) + [""]


def links_section(ctx: ReportContext, details: Path) -> list[str]:
    """Where the numbers and the per-cell details are (the details are not linked: they stay
    in the output folder, which may not be published with the page)."""
    return [
        f"Every number above is in [metrics.json]({link(ctx.out_dir / 'metrics.json', ctx.base)})"
        "; per-class metrics, confusion matrices and a plot of every cell are written by the "
        f"same command to `{details.as_posix()}`.",
        "",
    ]


def comparison_markdown(
    ctx: ReportContext,
    rows: list[dict[str, Any]],
    detections: dict[str, dict[str, dict[str, dict[str, Any]]]],
    details: Path,
) -> str:
    """The whole report, section by section."""
    return "\n".join(
        header_section(ctx)
        + accuracy_section(ctx, rows)
        + chessboard_section(ctx, rows)
        + peers_section(ctx, rows)
        + real_blur_section(ctx, rows)
        + margin_section(ctx, rows)
        + detection_section(detections)
        + links_section(ctx, details)
    )
