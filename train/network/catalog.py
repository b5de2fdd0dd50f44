"""models/README.md: which model to pick per object, what each shipped model is, its recipe,
the commands that rebuild it and its measured accuracy.

Written from the model cards (`<name>.json` beside each `<name>.onnx`, made by
`planar-pose export`; `role`, `use`, `training.recipe` and `training.rebuild` set by
`planar-pose card`), so the page always says what the files say.
"""

from __future__ import annotations

import json
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from service.core.paths import DEFAULT_MODEL_NAME
from train.markdown import machine, pct, table
from train.network.config import canonical_arch
from train.network.report import framing_line, margin_line, source_table

INTRO = f"""# Shipped models

Every `<name>.onnx` here has its model card beside it (`<name>.json`, also inside the ONNX
metadata as `model_card`): object profile, input size, classes, training data and recipe, and
the accuracies measured on the exported graph. `{DEFAULT_MODEL_NAME}.onnx` is what the service
answers with unless asked for another model. The graphs' inputs and outputs are
`service/core/onnx_contract.py`'s: `image` float32 [N, 3, H, W], RGB in [0, 1] (portraits
turned a quarter clockwise first) -> `probabilities` float32 [N, 9]; the corner networks also
take `pixel_aspect`, `view` and `focal` (each with a default) and give `corners` [N, 4, 2]
(input pixels, order (-X,-Y), (+X,-Y), (+X,+Y), (-X,+Y)) and `pattern` [N].

Accuracy columns are test splits: real = the corpus's test sources (cameras never used for
training or model selection), free / noC = renders of corpus-like cameras, spec = renders of
the SPEC's own camera (profile `chessboard-spec`), at blur level b (every name:
[docs/data.md](../docs/data.md#names)). Under
the default model (every model, in a folder without one), its real test figures by source at
the blur levels of the table, and, where its card has them (`export --eval-val`), those of
the real val sources it was selected on; the other models' are in their cards.

This page is written by `planar-pose catalog`; do not edit it by hand.

## Which model to pick

One model per object is its pick (`role` in its card); the others are ablations, kept because
a measured page compares them (docs/results.md, docs/comparison*.md), not for use.
"""


#: The card accuracies shown: (data set kind, blur level), as `export --eval` measures them.
COLUMNS = (("real", 0), ("real", 3), ("free", 0), ("free", 3), ("noC", 0), ("spec", 0), ("spec", 3))


def _cell(card: dict[str, Any], key: str) -> str:
    entry = card.get("accuracy", {}).get(key)
    return pct(entry["accuracy"]) if entry else ""


def _recipe(card: dict[str, Any], repo: Path) -> str:
    """The card's recipe, linked where `repo` (the models folder's parent) has the file; a
    card older than `training.rebuild` may name a command there instead."""
    recipe = card.get("training", {}).get("recipe") or ""
    if recipe and (repo / recipe).is_file():
        return f"[{Path(recipe).name}](../{recipe})"
    return f"`{recipe}`" if recipe else ""


def _row(card: dict[str, Any], repo: Path) -> list[Any]:
    """The table row of a card: name, role, network (its current name, `canonical_arch`),
    input, profile, recipe (`_recipe`) and the `COLUMNS` accuracies."""
    w, h = card["input"]
    s = 1 if (w, h) == (80, 60) else 2
    return [
        f"`{card['name']}`",
        card.get("role", ""),
        canonical_arch(card.get("architecture", "spec").split(":")[0]),
        f"{w}x{h}",
        card.get("profile", {}).get("name", ""),
        _recipe(card, repo),
        *(_cell(card, f"{d}-s{s}-b{b}") for d, b in COLUMNS),
    ]


def pick_table(cards: list[dict[str, Any]]) -> list[str]:
    """Per object (the profile's `object`, else its name): the model to pick and why (its
    card's `use`), and the ablations beside it."""
    objects: dict[str, list[dict[str, Any]]] = {}
    for card in cards:
        profile = card.get("profile", {})
        objects.setdefault(profile.get("object") or profile.get("name", ""), []).append(card)
    rows = []
    for name, group in objects.items():
        picks = [c for c in group if c.get("role") == "pick"]
        others = [f"`{c['name']}`" for c in group if c not in picks]
        for card in picks or [{"name": "", "use": "no model of this object is marked pick"}]:
            rows.append([name, f"`{card['name']}`" * bool(card["name"]), card.get("use", "")])
            rows[-1].append(", ".join(others))
    return table(["object", "pick", "why", "ablations"], rows)


def _rebuild_lines(card: dict[str, Any]) -> list[str]:
    """The commands that make the model again (`training.rebuild`), as a shell block."""
    commands = card.get("training", {}).get("rebuild") or []
    if not commands:
        return []
    return ["Rebuilt by:", "", "```bash", *commands, "```", ""]


def source_sections(card: dict[str, Any]) -> list[str]:
    """The card's real figures by source (`source_table`) at blur 0, test then val, each
    with its margin and framing lines (the other blur levels: the card's `by_source`)."""
    levels = {"-b0"}
    lines: list[str] = []
    for field, title in (
        ("accuracy", "Real test sources"),
        ("accuracy_val", "Real val sources (the model was selected on them)"),
    ):
        for key, entry in card.get(field, {}).items():
            if "by_source" not in entry or not any(key.endswith(b) for b in levels):
                continue
            lines += [f"{title}, `{key}`:", "", *source_table(entry["by_source"]), ""]
            for line in (
                margin_line(entry.get("by_margin")),
                framing_line(entry.get("by_framing")),
            ):
                lines += [line, ""] if line else []
    return lines


def catalog_lines(models_dir: Path) -> list[str]:
    """The lines of models_dir/README.md from the cards there, but the "Written" stamp.

    Per-source tables (`source_sections`) only for the service's default model
    (`service.core.paths.DEFAULT_MODEL_NAME`), or for every model when the folder has none;
    each model's notes as its card gives them.
    """
    cards = []
    for path in sorted(models_dir.glob("*.json")):
        card = json.loads(path.read_text())
        if isinstance(card, dict) and "input" in card:
            cards.append(card)
    if not cards:
        raise ValueError(f"no model card (*.json) in {models_dir}")
    names = [c["name"] for c in cards]
    detailed = [DEFAULT_MODEL_NAME] if DEFAULT_MODEL_NAME in names else names
    header = ["model", "role", "network", "input", "profile", "recipe"]
    header += [f"{d} b{b}" for d, b in COLUMNS]
    lines = [INTRO, *pick_table(cards), "", "## The models", ""]
    lines += [*table(header, [_row(c, models_dir.parent) for c in cards]), ""]
    for card in cards:
        version = f" ({card['version']})" if card.get("version") else ""
        lines += [f"## `{card['name']}`{version}", "", card.get("notes", ""), ""]
        lines += _rebuild_lines(card)
        if card["name"] in detailed:
            lines += source_sections(card)
        elif any("by_source" in e for e in card.get("accuracy", {}).values()):
            lines += [f"Its real figures by source: `{card['name']}.json` (`by_source`).", ""]
    return lines


def write_catalog(models_dir: Path) -> Path:
    """Write models_dir/README.md (`catalog_lines` and when and where it was written); return
    its path."""
    stamp = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    written = f"Written {stamp} on {machine()} by `planar-pose catalog`."
    lines = [*catalog_lines(models_dir), written]
    out = models_dir / "README.md"
    out.write_text("\n".join(lines) + "\n")
    return out
