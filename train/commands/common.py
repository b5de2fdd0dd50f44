"""What the `planar-pose` sub-commands share: consoles, clean exits on bad input, profiles."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import typer
from rich.console import Console
from rich.markup import escape

err = Console(stderr=True)
out = Console()


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
    from service.core.profile import load_profile

    return guard(lambda: load_profile(name_or_path))
