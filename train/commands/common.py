"""What the `planar-pose` sub-commands share: consoles, clean exits on bad input, profiles."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import typer
from rich.console import Console
from rich.markup import escape

from service.core.dataset import SPLITS
from service.core.inputs import SIZES
from service.core.profile import load_profile

err = Console(stderr=True)
out = Console()

#: What a --split option takes: a data set split, or all of them.
SPLIT_CHOICES = (*SPLITS, "all")


def fail(message: str, code: int = 1) -> typer.Exit:
    """Print `error: message` on stderr; return the typer.Exit(code) for the caller to raise.

    The message is printed as is: no rich markup, no wrapping inside paths.
    """
    err.print(f"[bold red]error:[/] {escape(message)}", soft_wrap=True)
    return typer.Exit(code)


def guard(body: Callable[[], Any], code: int = 1) -> Any:
    """Run a command body, turning expected input errors into a message and exit `code`."""
    try:
        return body()
    except (ValueError, KeyError, OSError) as exc:
        message = str(exc) if not isinstance(exc, KeyError) else f"missing field {exc}"
        raise fail(message, code) from None


def profile_or_exit(name_or_path: str) -> Any:
    """The object profile, or exit 1 with the loader's message (unknown profile, bad files)."""
    return guard(lambda: load_profile(name_or_path))


def size_or_exit(size: int) -> tuple[int, int]:
    """The input size (W, H) a --size option names, or exit 2 with the choices."""
    if size not in SIZES:
        choices = " or ".join(f"{i} ({w}x{h})" for i, (w, h) in SIZES.items())
        raise fail(f"--size must be {choices}, got {size}", code=2)
    return SIZES[size]


def split_or_exit(split: str) -> str | None:
    """The split a --split option names (None for "all"), or exit 2 with the choices."""
    if split not in SPLIT_CHOICES:
        raise fail(f"--split must be one of {', '.join(SPLIT_CHOICES)}, got {split!r}", code=2)
    return None if split == "all" else split
