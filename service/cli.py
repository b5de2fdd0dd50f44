"""`planar-pose-serve` (also `planar-pose serve`): run the HTTP service with uvicorn.

Settings: flags > POSE_* environment > defaults. This module imports nothing from `train`, so
the serving install (and the container image) needs no training code.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer
from pydantic import ValidationError
from rich.console import Console
from rich.markup import escape

err = Console(stderr=True)


def _error(message: str) -> None:
    """Print `error: message` on stderr as is (no markup, no wrapping inside paths)."""
    err.print(f"[bold red]error:[/] {escape(message)}", soft_wrap=True)


def serve(
    host: Annotated[str | None, typer.Option(help="Bind address [POSE_HOST, 127.0.0.1].")] = None,
    port: Annotated[
        int | None, typer.Option(min=1, max=65535, help="Port [POSE_PORT, 8000].")
    ] = None,
    model: Annotated[
        Path | None, typer.Option(help="ONNX model [POSE_MODEL_PATH, models/default.onnx].")
    ] = None,
    log_level: Annotated[
        str | None, typer.Option(help="critical, error, warning, info, debug [POSE_LOG_LEVEL].")
    ] = None,
) -> None:
    """Serve the pose model over HTTP (OpenAPI docs at /docs); SIGTERM drains requests."""
    import uvicorn

    from service.app import create_app
    from service.settings import Settings

    overrides: dict[str, Any] = {
        "host": host,
        "port": port,
        "model_path": model,
        "log_level": log_level,
    }
    try:
        settings = Settings(**{k: v for k, v in overrides.items() if v is not None})
    except ValidationError as exc:
        _error(f"invalid settings:\n{exc}")
        raise typer.Exit(2) from None
    path = settings.resolved_model_path
    if not path.is_file():
        _error(f"model file not found: {path}")
        raise typer.Exit(2)
    if settings.log_level.lower() not in uvicorn.config.LOG_LEVELS:
        _error(f"unknown log level {settings.log_level!r}")
        raise typer.Exit(2)
    uvicorn.run(
        create_app(settings),
        host=settings.host,
        port=settings.port,
        log_level=settings.log_level.lower(),
        access_log=settings.access_log,
        timeout_graceful_shutdown=settings.graceful_timeout_s,
    )


#: The service commands; `train.cli` merges them into the `planar-pose` app.
app = typer.Typer()
app.command()(serve)


#: `planar-pose-serve`: the same command on its own.
serve_app = typer.Typer(
    name="planar-pose-serve", pretty_exceptions_enable=False, add_completion=False
)
serve_app.command()(serve)


def main() -> None:
    """Entry point of the `planar-pose-serve` script."""
    serve_app()
