"""models/README.md: what each shipped model is, its recipe and its measured accuracy.

Written from the model cards (`<name>.json` beside each `<name>.onnx`, made by
`planar-pose export`), so the page always says what the files say.
"""

from __future__ import annotations

import json
import platform
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from train.markdown import pct, table
from train.network.report import framing_line, margin_line, source_table

INTRO = """# Shipped models

Every `<name>.onnx` here has its model card beside it (`<name>.json`, also inside the ONNX
metadata as `model_card`): object profile, input size, classes, training data and recipe, and
the accuracies measured on the exported graph. `default.onnx` is what the service answers
with unless asked for another model. Input: `image` float32 [N, 3, H, W], RGB in [0, 1]
(portraits turned a quarter clockwise first) and, for the keypoint networks of 3.4.0 on,
`pixel_aspect` float32 [N] (default 1; 4/3 for a 16:9 photo resized to the input); output:
`probabilities` float32 [N, 9] and, for the keypoint networks, `corners` float32 [N, 4, 2]
(the object's corners in input pixels, order (-X,-Y), (+X,-Y), (+X,+Y), (-X,+Y)).

Accuracy columns are test splits: real = the corpus's test sources (cameras never used for
training or model selection), free / noC = renders of corpus-like cameras, spec = renders of
the SPEC's own camera (profile `chessboard-spec`; see docs/data.md), at blur level b. Under
each model, its real test figures by source, and, where its card has them (`export
--eval-val`), those of the real val sources it was selected on.

This page is written by `planar-pose catalog`; do not edit it by hand.
"""


#: The card accuracies shown: (data set kind, blur level), as `export --eval` measures them.
COLUMNS = (("real", 0), ("real", 3), ("free", 0), ("free", 3), ("noC", 0), ("spec", 0), ("spec", 3))


def _cell(card: dict[str, Any], key: str) -> str:
    entry = card.get("accuracy", {}).get(key)
    return pct(entry["accuracy"]) if entry else ""


def _row(card: dict[str, Any]) -> list[Any]:
    w, h = card["input"]
    s = 1 if (w, h) == (80, 60) else 2
    recipe = card.get("training", {}).get("recipe") or ""
    return [
        f"`{card['name']}`",
        card.get("architecture", "spec").split(":")[0],
        f"{w}x{h}",
        card.get("profile", {}).get("name", ""),
        f"[{Path(recipe).name}](../{recipe})" if recipe else "",
        *(_cell(card, f"{d}-s{s}-b{b}") for d, b in COLUMNS),
    ]


def write_catalog(models_dir: Path) -> Path:
    """Write models_dir/README.md from the cards there; return its path."""
    cards = []
    for path in sorted(models_dir.glob("*.json")):
        card = json.loads(path.read_text())
        if isinstance(card, dict) and "input" in card:
            cards.append(card)
    if not cards:
        raise ValueError(f"no model card (*.json) in {models_dir}")
    header = ["model", "network", "input", "profile", "recipe", *(f"{d} b{b}" for d, b in COLUMNS)]
    lines = [INTRO, *table(header, [_row(c) for c in cards]), ""]
    for card in cards:
        lines += [f"## `{card['name']}`", "", card.get("notes", ""), ""]
        for field, title in (
            ("accuracy", "Real test sources"),
            ("accuracy_val", "Real val sources (the model was selected on them)"),
        ):
            for key, entry in card.get(field, {}).items():
                if "by_source" not in entry:
                    continue
                lines += [f"{title}, `{key}`:", "", *source_table(entry["by_source"]), ""]
                for line in (
                    margin_line(entry.get("by_margin")),
                    framing_line(entry.get("by_framing")),
                ):
                    lines += [line, ""] if line else []
    stamp = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    lines.append(f"Written {stamp} on {platform.node()} by `planar-pose catalog`.")
    out = models_dir / "README.md"
    out.write_text("\n".join(lines) + "\n")
    return out
