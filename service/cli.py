"""`planar-pose-serve` (also `planar-pose serve`): run the HTTP service with uvicorn.

Settings: flags > POSE_* environment > defaults. With more than one worker process, uvicorn
starts them (each builds its app from the environment, which this command fills in) and a
temporary runtime folder carries what they share: prometheus-client's multiprocess files,
readiness, reloads. This module imports nothing from `train`, so the serving install (and the
container image) needs no training code.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path
from typing import Annotated, Any

import typer
from pydantic import ValidationError
from rich.console import Console
from rich.markup import escape

from service.core.paths import DEFAULT_MODEL_DIR, repo_relative
from service.settings import Settings, cpu_count

err = Console(stderr=True)


def _error(message: str) -> None:
    """Print `error: message` on stderr as is (no markup, no wrapping inside paths)."""
    err.print(f"[bold red]error:[/] {escape(message)}", soft_wrap=True)


def _help(text: str, field: str) -> str:
    """An option's help with its variable and default, both read off `Settings`."""
    default = Settings.model_fields[field].default
    shown = repo_relative(DEFAULT_MODEL_DIR) if field == "model_dir" else default
    return f"{text} [POSE_{field.upper()}" + ("]" if shown is None else f", {shown}]")


def _settings(overrides: dict[str, Any]) -> Settings:
    """Settings from flags and environment, or exit 2 with the reason."""
    import uvicorn

    try:
        settings = Settings(**{k: v for k, v in overrides.items() if v is not None})
    except ValidationError as exc:
        _error(f"invalid settings:\n{exc}")
        raise typer.Exit(2) from None
    if settings.model_path is not None and not settings.model_path.is_file():
        _error(f"model file not found: {settings.model_path}")
        raise typer.Exit(2)
    if settings.model_path is None and not settings.resolved_model_dir.is_dir():
        _error(f"model folder not found: {settings.resolved_model_dir}")
        raise typer.Exit(2)
    if settings.log_level.lower() not in uvicorn.config.LOG_LEVELS:
        _error(f"unknown log level {settings.log_level!r}")
        raise typer.Exit(2)
    return settings


#: Where temporary files may go when TMPDIR, /tmp and /var/tmp cannot be written (a container
#: with a read-only root: Docker and Kubernetes give every container a writable /dev/shm).
FALLBACK_TMP = (Path("/dev/shm"),)


def usable_tmp() -> Path:
    """A folder this process can make temporary files in: Python's own choice (TMPDIR, /tmp,
    /var/tmp, ...), else /dev/shm, which then becomes TMPDIR for this process and its workers
    (multipart uploads larger than 1 MB are spooled there). Exit 2 saying what to mount when
    there is none."""
    try:
        return Path(tempfile.gettempdir())
    except FileNotFoundError:
        pass
    for folder in FALLBACK_TMP:
        if folder.is_dir() and os.access(folder, os.W_OK | os.X_OK):
            os.environ["TMPDIR"] = str(folder)
            tempfile.tempdir = str(folder)
            return folder
    _error(
        "no writable temporary folder (TMPDIR, /tmp, /var/tmp, /dev/shm): on a read-only root, "
        "mount one (docker/podman run --tmpfs /tmp, a Kubernetes emptyDir at /tmp) or set TMPDIR"
    )
    raise typer.Exit(2)


def _worker_environment(settings: Settings, overrides: dict[str, Any], runtime: Path) -> None:
    """Put the flags and the runtime folder into os.environ for the worker processes."""
    for key, value in overrides.items():
        if value is not None:
            os.environ[f"POSE_{key.upper()}"] = str(value)
    workers = settings.process_count
    os.environ["POSE_WORKERS"] = str(workers)
    os.environ["POSE_RUNTIME_DIR"] = str(runtime)
    if not settings.inference_workers:  # share the CPUs between the workers
        os.environ["POSE_INFERENCE_WORKERS"] = str(max(1, cpu_count() // workers))
    metrics = runtime / "metrics"
    metrics.mkdir()
    os.environ["PROMETHEUS_MULTIPROC_DIR"] = str(metrics)


def serve(
    host: Annotated[str | None, typer.Option(help=_help("Bind address", "host"))] = None,
    port: Annotated[int | None, typer.Option(min=1, max=65535, help=_help("Port", "port"))] = None,
    workers: Annotated[
        int | None,
        typer.Option(min=0, help=_help("Worker processes, 0 = one per CPU", "workers")),
    ] = None,
    model_dir: Annotated[
        Path | None,
        typer.Option(help=_help("Model folder: every <name>.onnx is served", "model_dir")),
    ] = None,
    model: Annotated[
        Path | None,
        typer.Option(help=_help("One ONNX file served as the default model", "model_path")),
    ] = None,
    log_level: Annotated[
        str | None, typer.Option(help=_help("critical, error, warning, info, debug", "log_level"))
    ] = None,
) -> None:
    """Serve the pose models over HTTP (OpenAPI docs at /docs); SIGTERM drains requests."""
    import uvicorn

    overrides: dict[str, Any] = {
        "host": host,
        "port": port,
        "workers": workers,
        "model_dir": model_dir,
        "model_path": model,
        "log_level": log_level,
    }
    settings = _settings(overrides)
    tmp = usable_tmp()
    options: dict[str, Any] = {
        "host": settings.host,
        "port": settings.port,
        "log_level": settings.log_level.lower(),
        "access_log": settings.access_log,
        "timeout_graceful_shutdown": settings.graceful_timeout_s,
        # A stream frame as large as an upload reaches the route, which answers it with its
        # payload_too_large message instead of the connection being cut.
        "ws_max_size": settings.max_upload_bytes + 4096,
    }
    if settings.process_count == 1:
        from service.app import create_app

        uvicorn.run(create_app(settings), **options)
        return
    runtime = Path(tempfile.mkdtemp(prefix="planar-pose-serve-", dir=tmp))
    try:
        from service.supervisor import Supervisor

        _worker_environment(settings, overrides, runtime)
        config = uvicorn.Config(
            "service.app:create_app", factory=True, workers=settings.process_count, **options
        )
        Supervisor(config, sockets=[config.bind_socket()]).run()
    finally:
        shutil.rmtree(runtime, ignore_errors=True)


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


if __name__ == "__main__":  # `python -m service.cli`: this checkout's code, not an install's
    main()
