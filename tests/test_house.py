"""The repository's own rules: every shipped model's card names its recipe in recipes/ and
the commands that rebuild it (each `planar-pose` one a valid command line), and no folder
outside the repository; the ONNX's copy of each card is its .json; one pick per object;
models/README.md is what `planar-pose catalog` writes from the cards; every relative link and
repository path of the pages resolves; no function over 80 lines; README.md within 180
lines."""

from __future__ import annotations

import ast
import json
import re
import shlex
from collections import Counter
from fnmatch import fnmatch
from pathlib import Path
from typing import Any

import onnx
import pytest
import typer

from service.core.onnx_contract import CARD_KEY
from service.core.paths import REPO_ROOT
from train.network.catalog import catalog_lines
from train.network.export import ROLES

MODELS = sorted((REPO_ROOT / "models").glob("*.onnx"))
#: The top folders a repository path in a page or a card starts with.
TOP = ("train", "service", "docs", "scripts", "recipes", "models", "tests", "benchmarks")
TOP += ("clients", "deploy", ".ci")
REPO_PATH = re.compile(rf"(?<![\w./-])((?:{'|'.join(map(re.escape, TOP))})/[\w./+*<>{{}},-]*)")
#: A path that stands for many (`NAME`, `<name>`, a glob, `{a,b}`, `my-model`): not checked.
PLACEHOLDER = re.compile(r"[<>*{}]|NAME|\.\.\.|\bmy-")
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")
#: Functions longer than this many lines are split (the code under these folders).
MAX_FUNCTION_LINES, CODE = 80, ("service", "train", "scripts", "benchmarks", "clients/python")


def _card(path: Path) -> dict[str, Any]:
    return json.loads(path.with_suffix(".json").read_text())


def _strings(value: Any) -> list[str]:
    """Every string in a card (nested dicts and lists)."""
    if isinstance(value, str):
        return [value]
    if isinstance(value, dict):
        return [s for v in value.values() for s in _strings(v)]
    if isinstance(value, list):
        return [s for v in value for s in _strings(v)]
    return []


def _missing_paths(text: str) -> list[str]:
    """The repository paths named in `text` (`REPO_PATH`, placeholders left out) that do
    not exist, but for those in a folder git ignores because a command writes it
    (.gitignore's `/...` lines, e.g. docs/results/details/)."""
    written = [
        line.strip().strip("/") + "*"
        for line in (REPO_ROOT / ".gitignore").read_text().splitlines()
        if line.startswith("/")
    ]
    return [
        path
        for path in (m.group(1).rstrip(".,") for m in REPO_PATH.finditer(text))
        if not PLACEHOLDER.search(path)
        and not any(fnmatch(path, pattern) for pattern in written)
        and not (REPO_ROOT / path).exists()
    ]


@pytest.mark.parametrize("model", MODELS, ids=lambda p: p.stem)
def test_a_shipped_cards_recipe_and_rebuild_commands_are_in_the_repository(model: Path) -> None:
    card = _card(model)
    recipe = card["training"]["recipe"]
    assert recipe.startswith("recipes/") and (REPO_ROOT / recipe).is_file(), recipe
    rebuild = card["training"]["rebuild"]
    assert rebuild and all(isinstance(c, str) and c for c in rebuild)
    for command in rebuild:
        for word in command.split():
            if word.startswith(("recipes/", "scripts/")):
                assert (REPO_ROOT / word).is_file(), f"{model.name}: {command}"
    assert card["role"] in ROLES and card["use"]


def _parsed(words: list[str]) -> None:
    """A `planar-pose` command line's words after the program's name parsed by the CLI (its
    options and arguments checked, nothing run); a click usage error where they are wrong."""
    from train.cli import app

    command, name = typer.main.get_command(app), "planar-pose"
    while hasattr(command, "commands"):  # a group: its subcommand
        name, words = words[0], words[1:]
        command = command.commands[name]
    command.make_context(name, words)


def test_the_parser_refuses_a_wrong_command_line() -> None:
    with pytest.raises(Exception, match="No such option: --bogus"):
        _parsed(["object", "train", "book", "--bogus"])


@pytest.mark.parametrize("model", MODELS, ids=lambda p: p.stem)
def test_a_cards_planar_pose_rebuild_commands_parse(model: Path) -> None:
    for command in _card(model)["training"]["rebuild"]:
        words = shlex.split(command)
        if words[0] == "planar-pose":
            _parsed(words[1:])


@pytest.mark.parametrize("model", MODELS, ids=lambda p: p.stem)
def test_a_card_names_no_folder_outside_the_repository_and_its_onnx_copy_agrees(
    model: Path,
) -> None:
    card = _card(model)
    for text in _strings(card):
        assert not re.search(r"(?<![\w.])/(tmp|home|work|root|Users|mnt|var|opt)/", text), text
        assert not _missing_paths(text), (model.name, _missing_paths(text))
    meta = {p.key: p.value for p in onnx.load(str(model), load_external_data=False).metadata_props}
    assert json.loads(meta[CARD_KEY]) == card


def test_each_object_has_one_pick_and_the_catalog_says_what_the_cards_say() -> None:
    picks = Counter(
        _card(m)["profile"].get("object") or _card(m)["profile"]["name"]
        for m in MODELS
        if _card(m)["role"] == "pick"
    )
    objects = {_card(m)["profile"].get("object") or _card(m)["profile"]["name"] for m in MODELS}
    assert picks == Counter(objects)
    *written, stamp = (REPO_ROOT / "models" / "README.md").read_text().splitlines()
    assert stamp.startswith("Written ") and "planar-pose catalog" in stamp
    expected = "\n".join(catalog_lines(REPO_ROOT / "models")).split("\n")
    assert written == expected, "models/README.md is not the cards': run `planar-pose catalog`"


def test_the_checks_see_a_missing_path_a_placeholder_and_an_ignored_folder() -> None:
    assert _missing_paths("see `train/network/keypoint.py` and recipes/gone.toml.") == [
        "train/network/keypoint.py",
        "recipes/gone.toml",
    ]
    assert not _missing_paths("recipes/NAME.toml, models/<name>.onnx, recipes/x-*.toml")
    assert not _missing_paths("docs/results/details/details.md, models/my-model.onnx")
    assert LINK.findall("[a](../b.md) and [c](https://x.org/d)") == ["../b.md", "https://x.org/d"]


def _pages() -> list[Path]:
    skip = {".venv", "node_modules", ".git", "runs"}
    return [
        p
        for p in sorted(REPO_ROOT.rglob("*.md"))
        if not skip.intersection(p.relative_to(REPO_ROOT).parts)
    ]


@pytest.mark.parametrize("page", _pages(), ids=lambda p: str(p.relative_to(REPO_ROOT)))
def test_every_link_and_repository_path_of_a_page_resolves(page: Path) -> None:
    text = page.read_text()
    broken = [
        target
        for target in (t.split("#")[0] for t in LINK.findall(text))
        if target and not re.match(r"[a-z]+:", target) and not (page.parent / target).exists()
    ]
    assert not broken, f"{page.relative_to(REPO_ROOT)}: links to {broken}"
    missing = _missing_paths(text)
    assert not missing, f"{page.relative_to(REPO_ROOT)}: names {missing}"


def test_no_function_is_longer_than_80_lines() -> None:
    long = []
    for folder in CODE:
        for path in sorted((REPO_ROOT / folder).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                    lines = node.end_lineno - node.lineno + 1  # type: ignore[operator]
                    if lines > MAX_FUNCTION_LINES:
                        long.append(f"{path.relative_to(REPO_ROOT)}:{node.name} ({lines})")
    assert not long, long


def test_the_readme_stays_within_180_lines() -> None:
    assert len((REPO_ROOT / "README.md").read_text().splitlines()) <= 180
