"""The `planar-pose-client` command: call a running planar-pose service from the shell.

    planar-pose-client predict photo1.jpg photo2.png [--mode sliding] [--json]
    planar-pose-client info [--json]
    planar-pose-client status

`--url` (env PLANAR_POSE_URL, default http://127.0.0.1:8000) and `--api-key`
(env PLANAR_POSE_API_KEY) pick the service. Failures print one line `error: ...` on stderr and
exit with a code that says what went wrong (see `ExitCode`); never a traceback.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from contextlib import contextmanager
from enum import IntEnum, StrEnum
from pathlib import Path
from typing import Annotated

try:
    import typer
    from rich.console import Console
    from rich.table import Table
except ImportError as exc:  # the SDK itself needs neither; only this command does
    raise SystemExit(
        "planar-pose-client: the command needs typer and rich: "
        "pip install 'planar-pose-client[cli]'"
    ) from exc

from .client import PoseClient
from .errors import (
    AuthError,
    BadImageError,
    PoseConnectionError,
    PoseError,
    ServiceUnavailable,
    TooLargeError,
    UnsupportedMediaError,
)
from .images import check_path
from .models import ModelCard, Prediction


class ExitCode(IntEnum):
    """Exit status of the command (2 is also what typer uses for a bad command line)."""

    OK = 0
    SERVICE_ERROR = 1  # any other error answer of the service (e.g. 422, 500)
    USAGE = 2
    UNREACHABLE = 3  # no answer, or 503 (not ready)
    AUTH = 4  # 401: API key missing or wrong
    BAD_INPUT = (
        5  # missing/unreadable file, bad URL, or the service refused the image (400, 413, 415)
    )


class ModeChoice(StrEnum):
    whole = "whole"
    sliding = "sliding"


app = typer.Typer(
    name="planar-pose-client",
    help="Ask a planar-pose service from which region of space an object is seen.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)

UrlOption = Annotated[
    str, typer.Option("--url", envvar="PLANAR_POSE_URL", help="Base URL of the service.")
]
KeyOption = Annotated[
    str | None,
    typer.Option(
        "--api-key",
        envvar="PLANAR_POSE_API_KEY",
        help="API key, when the service requires one.",
        show_default=False,
    ),
]
TimeoutOption = Annotated[float, typer.Option("--timeout", min=0.1, help="Seconds per request.")]
RetriesOption = Annotated[
    int, typer.Option("--retries", min=0, help="Extra attempts when unreachable or 503.")
]
JsonOption = Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")]

DEFAULT_URL = "http://127.0.0.1:8000"


@app.command()
def predict(
    images: Annotated[list[Path], typer.Argument(help="Image files (JPEG, PNG, WebP, BMP).")],
    mode: Annotated[
        ModeChoice, typer.Option("--mode", help="whole: one look; sliding: search windows.")
    ] = ModeChoice.whole,
    as_json: JsonOption = False,
    url: UrlOption = DEFAULT_URL,
    api_key: KeyOption = None,
    timeout: TimeoutOption = 30.0,
    retries: RetriesOption = 2,
    batch: Annotated[
        int, typer.Option("--batch", min=1, help="Images per request (the service's limit).")
    ] = 16,
) -> None:
    """Predict the pose region of each IMAGE, sending them `--batch` at a time."""
    predictions: list[Prediction] = []
    with _errors_as_exit_codes(), PoseClient(url, api_key, timeout=timeout, retries=retries) as c:
        for path in images:  # all files exist before the first request
            check_path(path)
        for start in range(0, len(images), batch):
            predictions += c.predict_many(images[start : start + batch], mode=mode.value)
    if as_json:
        typer.echo(json.dumps([p.model_dump(mode="json") for p in predictions], indent=2))
    else:
        Console().print(_prediction_table(predictions, mode.value))


@app.command()
def info(
    as_json: JsonOption = False,
    url: UrlOption = DEFAULT_URL,
    api_key: KeyOption = None,
    timeout: TimeoutOption = 30.0,
    retries: RetriesOption = 2,
) -> None:
    """Show the served model's card: name, version, input size, classes, accuracy."""
    with _errors_as_exit_codes(), PoseClient(url, api_key, timeout=timeout, retries=retries) as c:
        card = c.model_info()
    if as_json:
        typer.echo(card.model_dump_json(indent=2))
    else:
        Console().print(_card_table(card))


@app.command()
def status(url: UrlOption = DEFAULT_URL, timeout: TimeoutOption = 5.0) -> None:
    """Say whether the service is alive and ready; exit 0 only when it is ready."""
    with _errors_as_exit_codes(), PoseClient(url, timeout=timeout) as c:
        alive, ready = c.health(), c.ready()
    alive_text = "alive" if alive else "not answering"
    typer.echo(f"{url}: {alive_text}, {'ready' if ready else 'not ready'}")
    if not ready:
        raise typer.Exit(ExitCode.UNREACHABLE)


def main() -> None:
    """Entry point of the `planar-pose-client` script."""
    app()


@contextmanager
def _errors_as_exit_codes() -> Iterator[None]:
    """Print any expected failure as one `error: ...` line on stderr and exit with its code."""
    try:
        yield
    except (PoseError, OSError, TypeError, ValueError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(_exit_code(exc)) from None


def _exit_code(exc: Exception) -> ExitCode:
    if isinstance(exc, PoseConnectionError | ServiceUnavailable):
        return ExitCode.UNREACHABLE
    if isinstance(exc, AuthError):
        return ExitCode.AUTH
    if isinstance(exc, BadImageError | TooLargeError | UnsupportedMediaError):
        return ExitCode.BAD_INPUT
    if isinstance(exc, PoseError):
        return ExitCode.SERVICE_ERROR
    return ExitCode.BAD_INPUT  # local: missing or unreadable file, empty image


def _prediction_table(predictions: list[Prediction], mode: str) -> Table:
    table = Table(title=f"{len(predictions)} image(s), mode {mode}")
    for name, justify in (
        ("file", "left"),
        ("class", "right"),
        ("region", "left"),
        ("confidence", "right"),
        ("box x,y wxh", "left"),
        ("ms", "right"),
    ):
        table.add_column(name, justify=justify)  # type: ignore[arg-type]
    for p in predictions:
        box = f"{p.box.x},{p.box.y} {p.box.w}x{p.box.h}" if p.box else "-"
        table.add_row(
            p.filename or "-",
            str(p.class_id),
            p.label,
            f"{p.confidence:.3f}",
            box,
            f"{p.elapsed_ms:.1f}",
        )
    return table


def _card_table(card: ModelCard) -> Table:
    table = Table(title=f"model {card.name}", show_header=False)
    table.add_column("field", style="bold")
    table.add_column("value")
    table.add_row("version", card.version)
    table.add_row("input", f"{card.input[0]}x{card.input[1]} px (W x H)")
    for field in ("date", "notes", "accuracy", "profile", "training"):
        value = getattr(card, field)
        if value:
            table.add_row(field, _short(value))
    for info in card.classes:
        table.add_row(f"class {info.id}", _short(info.description or info.label))
    return table


def _short(value: object) -> str:
    """A card field on one line: dicts as `key=value` pairs, long text cut at 100 characters."""
    if isinstance(value, dict):
        text = ", ".join(f"{k}={_short(v)}" for k, v in value.items())
    elif isinstance(value, float):
        text = f"{value:.4g}"
    else:
        text = str(value)
    return text if len(text) <= 100 else text[:99] + "…"
