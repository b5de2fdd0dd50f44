"""The `planar-pose-client` command: call a running planar-pose service from the shell.

    planar-pose-client predict photo1.jpg photo2.png [--mode sliding] [--model NAME]
        [--fx PX | --camera ID] [--regions 8x3x60] [--same-camera] [--json]
    planar-pose-client info [--json]
    planar-pose-client models [--json]
    planar-pose-client status
    planar-pose-client watch video.mp4|0 [--mode sliding] [--camera ID] [--out drawn.mp4]
    planar-pose-client cameras list|show ID|add --fx PX ...|learn PHOTO...|delete ID

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
from typing import Annotated, Any, NoReturn

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
    CameraNotFoundError,
    ModelNotFoundError,
    PoseConnectionError,
    PoseError,
    ServiceUnavailable,
    TooLargeError,
    UnsupportedMediaError,
)
from .images import check_path
from .models import Camera, ModelCard, ModelList, Pose, Prediction
from .stream import DEFAULT_WINDOW, FrameError, StreamItem, StreamMode, StreamPrediction


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
    UNKNOWN_MODEL = 6  # 404: no served model of that name (`models` lists them)
    UNKNOWN_CAMERA = 7  # 404: no stored camera of that id (`cameras list` lists them)


class ModeChoice(StrEnum):
    whole = "whole"
    sliding = "sliding"
    proposals = "proposals"


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
CameraOption = Annotated[
    str | None,
    typer.Option(
        "--camera",
        help="A stored camera's id (see `cameras list`): its focal length for the pose.",
        show_default=False,
    ),
]

DEFAULT_URL = "http://127.0.0.1:8000"


@app.command()
def predict(
    images: Annotated[list[Path], typer.Argument(help="Image files (JPEG, PNG, WebP, BMP).")],
    mode: Annotated[
        ModeChoice,
        typer.Option(
            "--mode", help="whole: one look; sliding: search windows; proposals: object boxes."
        ),
    ] = ModeChoice.whole,
    model: Annotated[
        str | None,
        typer.Option("--model", help="Served model name (see `models`; default: the default)."),
    ] = None,
    fx: Annotated[
        float | None,
        typer.Option(
            "--fx",
            min=0.001,
            help="The camera's focal length in pixels of the images (calibration), if known.",
        ),
    ] = None,
    camera: CameraOption = None,
    regions: Annotated[
        str | None,
        typer.Option(
            "--regions",
            metavar="GRID",
            help="Finer regions of the pose: AxE or AxExD1,D2,... (azimuth sectors x "
            "elevation bands x distance splits in cm), e.g. 8x3x60.",
            show_default=False,
        ),
    ] = None,
    same_camera: Annotated[
        bool,
        typer.Option(
            "--same-camera",
            help="The images come from one camera: one focal length fitted to all of them "
            "(they go in one request).",
        ),
    ] = False,
    as_json: JsonOption = False,
    url: UrlOption = DEFAULT_URL,
    api_key: KeyOption = None,
    timeout: TimeoutOption = 30.0,
    retries: RetriesOption = 2,
    batch: Annotated[
        int, typer.Option("--batch", min=1, help="Images per request (the service's limit).")
    ] = 16,
) -> None:
    """Predict the pose region of each IMAGE, sending them `--batch` at a time; whole mode
    with a corner model also gives the camera's pose (distance, azimuth, elevation)."""
    if same_camera and len(images) > batch:
        _usage_error(
            f"--same-camera fits one focal length to the images of one request: give at "
            f"most --batch ({batch}) images, or a larger --batch (the service has a limit)"
        )
    predictions: list[Prediction] = []
    with _errors_as_exit_codes(), PoseClient(url, api_key, timeout=timeout, retries=retries) as c:
        for path in images:  # all files exist before the first request
            check_path(path)
        for start in range(0, len(images), batch):
            predictions += c.predict_many(
                images[start : start + batch],
                mode.value,
                model,
                fx,
                camera=camera,
                regions=regions,
                same_camera=same_camera,
            )
    if as_json:
        typer.echo(json.dumps([p.model_dump(mode="json") for p in predictions], indent=2))
        return
    console = Console()
    console.print(_prediction_table(predictions, mode.value))
    if any(p.pose is not None for p in predictions):
        console.print(_pose_table(predictions))
    if any(p.cell is not None for p in predictions):
        console.print(_cell_table(predictions))


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
def models(
    as_json: JsonOption = False,
    url: UrlOption = DEFAULT_URL,
    api_key: KeyOption = None,
    timeout: TimeoutOption = 30.0,
    retries: RetriesOption = 2,
) -> None:
    """List the served models (name for `--model`, input size, object, default)."""
    with _errors_as_exit_codes(), PoseClient(url, api_key, timeout=timeout, retries=retries) as c:
        listing = c.models()
    if as_json:
        typer.echo(listing.model_dump_json(indent=2))
    else:
        Console().print(_models_table(listing))


@app.command()
def status(url: UrlOption = DEFAULT_URL, timeout: TimeoutOption = 5.0) -> None:
    """Say whether the service is alive and ready; exit 0 only when it is ready."""
    with _errors_as_exit_codes(), PoseClient(url, timeout=timeout) as c:
        alive, ready = c.health(), c.ready()
    alive_text = "alive" if alive else "not answering"
    typer.echo(f"{url}: {alive_text}, {'ready' if ready else 'not ready'}")
    if not ready:
        raise typer.Exit(ExitCode.UNREACHABLE)


# --- cameras: the focal lengths the service stores (camera=ID) -----------------------------

cameras_app = typer.Typer(
    help="Cameras the service stores: give one by its intrinsics or let it learn one from "
    "photos; `--camera ID` on predict and watch uses it.",
    no_args_is_help=True,
)
app.add_typer(cameras_app, name="cameras")

CameraIdArgument = Annotated[
    str, typer.Argument(metavar="ID", help="The camera's id (see `cameras list`).")
]
NameOption = Annotated[
    str | None, typer.Option("--name", help="A name to know it by.", show_default=False)
]


@cameras_app.command("list")
def cameras_list(
    as_json: JsonOption = False,
    url: UrlOption = DEFAULT_URL,
    api_key: KeyOption = None,
    timeout: TimeoutOption = 30.0,
    retries: RetriesOption = 2,
) -> None:
    """List the stored cameras, newest first."""
    with _errors_as_exit_codes(), PoseClient(url, api_key, timeout=timeout, retries=retries) as c:
        cameras = c.cameras()
    if as_json:
        typer.echo(json.dumps([cam.model_dump(mode="json") for cam in cameras], indent=2))
    else:
        Console().print(_cameras_table(cameras))


@cameras_app.command("show")
def cameras_show(
    camera_id: CameraIdArgument,
    as_json: JsonOption = False,
    url: UrlOption = DEFAULT_URL,
    api_key: KeyOption = None,
    timeout: TimeoutOption = 30.0,
    retries: RetriesOption = 2,
) -> None:
    """Show one stored camera."""
    with _errors_as_exit_codes(), PoseClient(url, api_key, timeout=timeout, retries=retries) as c:
        camera = c.camera(camera_id)
    _print_camera(camera, as_json)


def _parse_dist(value: str | None) -> list[float] | None:
    if value is None:
        return None
    try:
        return [float(k) for k in value.split(",")]
    except ValueError:
        _usage_error(f"--dist takes numbers separated by commas (k1,k2,p1,p2[,k3]), got {value!r}")


@cameras_app.command("add")
def cameras_add(
    fx: Annotated[float, typer.Option("--fx", min=0.001, help="Focal length, px (at --width).")],
    fy: Annotated[
        float | None,
        typer.Option("--fy", min=0.001, help="Vertical focal length, px (default: fx)."),
    ] = None,
    cx: Annotated[
        float | None, typer.Option("--cx", help="Principal point x, px (default: centre).")
    ] = None,
    cy: Annotated[
        float | None, typer.Option("--cy", help="Principal point y, px (default: centre).")
    ] = None,
    dist: Annotated[
        str | None,
        typer.Option(
            "--dist",
            metavar="K1,K2,P1,P2[,K3]",
            help="OpenCV distortion coefficients.",
            show_default=False,
        ),
    ] = None,
    width: Annotated[
        int | None,
        typer.Option("--width", min=1, help="Image width fx is given at, px (fx scales with it)."),
    ] = None,
    height: Annotated[int | None, typer.Option("--height", min=1, help="Image height, px.")] = None,
    name: NameOption = None,
    as_json: JsonOption = False,
    url: UrlOption = DEFAULT_URL,
    api_key: KeyOption = None,
    timeout: TimeoutOption = 30.0,
    retries: RetriesOption = 2,
) -> None:
    """Store a camera given by its intrinsics (e.g. from a calibration); prints its id."""
    coefficients = _parse_dist(dist)
    with _errors_as_exit_codes(), PoseClient(url, api_key, timeout=timeout, retries=retries) as c:
        camera = c.create_camera(
            fx, fy=fy, cx=cx, cy=cy, dist=coefficients, width=width, height=height, name=name
        )
    _print_camera(camera, as_json)


@cameras_app.command("learn")
def cameras_learn(
    photos: Annotated[
        list[Path],
        typer.Argument(
            metavar="PHOTO...",
            help="3 or more photos of the object by that camera, from different angles, "
            "all of one size.",
        ),
    ],
    model: Annotated[
        str | None,
        typer.Option("--model", help="Corner model that finds the object (default: default)."),
    ] = None,
    name: NameOption = None,
    as_json: JsonOption = False,
    url: UrlOption = DEFAULT_URL,
    api_key: KeyOption = None,
    timeout: Annotated[
        float, typer.Option("--timeout", min=0.1, help="Seconds for the request (the fit).")
    ] = 120.0,
    retries: RetriesOption = 2,
) -> None:
    """Let the service learn a camera's focal length from photos of the object; prints its
    id."""
    with _errors_as_exit_codes(), PoseClient(url, api_key, timeout=timeout, retries=retries) as c:
        for path in photos:  # all files exist before the request
            check_path(path)
        camera = c.learn_camera(photos, model=model, name=name)
    _print_camera(camera, as_json)


@cameras_app.command("delete")
def cameras_delete(
    camera_id: CameraIdArgument,
    url: UrlOption = DEFAULT_URL,
    api_key: KeyOption = None,
    timeout: TimeoutOption = 30.0,
    retries: RetriesOption = 2,
) -> None:
    """Forget a stored camera."""
    with _errors_as_exit_codes(), PoseClient(url, api_key, timeout=timeout, retries=retries) as c:
        c.delete_camera(camera_id)
    typer.echo(f"deleted camera {camera_id}")


def _print_camera(camera: Camera, as_json: bool) -> None:
    if as_json:
        typer.echo(camera.model_dump_json(indent=2))
    else:
        Console().print(_camera_table(camera))


def _size(camera: Camera) -> str:
    if camera.width is None:
        return "any"
    return f"{camera.width}x{camera.height}" if camera.height is not None else f"{camera.width}"


def _principal_point(camera: Camera) -> str | None:
    if camera.cx is None and camera.cy is None:
        return None  # the image centre
    return ", ".join("-" if v is None else f"{v:.1f}" for v in (camera.cx, camera.cy)) + " px"


def _cameras_table(cameras: list[Camera]) -> Table:
    table = Table(title=f"{len(cameras)} camera(s)")
    for name in ("id", "name", "fx px", "size", "source", "created"):
        table.add_column(name, justify="right" if name == "fx px" else "left")
    for cam in cameras:
        created = cam.created.strftime("%Y-%m-%d %H:%M") if cam.created else "-"
        source: str = cam.source
        if cam.source == "photos" and cam.photos_used:
            source += f" ({cam.photos_used})"
        table.add_row(cam.id, cam.name or "-", f"{cam.fx:.1f}", _size(cam), source, created)
    return table


def _camera_table(camera: Camera) -> Table:
    table = Table(title=f"camera {camera.id}", show_header=False)
    table.add_column("field", style="bold")
    table.add_column("value")
    table.add_row("id", camera.id)
    rows: list[tuple[str, object]] = [
        ("name", camera.name),
        ("fx", f"{camera.fx:.1f} px"),
        ("fy", None if camera.fy is None else f"{camera.fy:.1f} px"),
        ("cx, cy", _principal_point(camera)),
        ("dist", None if camera.dist is None else ", ".join(f"{k:g}" for k in camera.dist)),
        ("size", _size(camera) + (" (fx scales with the image width)" if camera.width else "")),
        ("source", camera.source),
        ("photos used", camera.photos_used if camera.source == "photos" else None),
        ("residual", None if camera.residual_px is None else f"{camera.residual_px:.2f} px"),
        (
            "fx range",
            None if camera.fx_range is None else "{:.0f}-{:.0f} px".format(*camera.fx_range),
        ),
        ("created", camera.created.isoformat() if camera.created else None),
    ]
    for field, value in rows:
        if value is not None:
            table.add_row(field, str(value))
    return table


def main() -> None:
    """Entry point of the `planar-pose-client` script."""
    app()


def _usage_error(message: str) -> NoReturn:
    """A bad combination of options: one `error: ...` line and exit code 2."""
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(ExitCode.USAGE)


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
    if isinstance(exc, CameraNotFoundError):
        return ExitCode.UNKNOWN_CAMERA
    if isinstance(exc, ModelNotFoundError):
        return ExitCode.UNKNOWN_MODEL
    if isinstance(exc, BadImageError | TooLargeError | UnsupportedMediaError):
        return ExitCode.BAD_INPUT
    if isinstance(exc, PoseError):
        return ExitCode.SERVICE_ERROR
    return ExitCode.BAD_INPUT  # local: missing or unreadable file, empty image


def _prediction_table(predictions: list[Prediction], mode: str) -> Table:
    # With poses, the focal length is in the pose table (with where it came from).
    with_fx = all(p.pose is None for p in predictions)
    table = Table(title=f"{len(predictions)} image(s), mode {mode}")
    columns = ["file", "class", "region", "confidence", "box x,y wxh", "fx px", "ms"]
    for name in columns if with_fx else [c for c in columns if c != "fx px"]:
        right = name in ("class", "confidence", "fx px", "ms")
        table.add_column(name, justify="right" if right else "left")
    for p in predictions:
        box = f"{p.box.x},{p.box.y} {p.box.w}x{p.box.h}" if p.box else "-"
        fx = f"{p.fx:.0f} ({p.fx_source})" if p.fx is not None else "-"  # "-": estimated
        table.add_row(
            p.filename or "-",
            str(p.class_id),
            p.label,
            f"{p.confidence:.3f}",
            box,
            *((fx,) if with_fx else ()),
            f"{p.elapsed_ms:.1f}",
        )
    return table


def _pose_table(predictions: list[Prediction]) -> Table:
    """Where the camera is, per image: distance (and its range where fx was estimated),
    azimuth, elevation, the focal length and where it came from, the corners' RMS error."""
    table = Table(title="camera pose (object frame; cm, degrees)")
    for name in ("file", "distance cm", "az deg", "el deg", "fx px (from)", "rms px"):
        table.add_column(name, justify="left" if name == "file" else "right")
    for p in predictions:
        if p.pose is None:
            table.add_row(p.filename or "-", "-", "-", "-", "-", "-")
            continue
        pose = p.pose
        table.add_row(
            p.filename or "-",
            _distance(pose),
            f"{pose.azimuth_deg:.0f}",
            f"{pose.elevation_deg:.0f}",
            f"{pose.fx:.0f} ({pose.fx_source})",
            f"{pose.residual_px:.1f}",
        )
    return table


def _distance(pose: Pose) -> str:
    """e.g. "58.8" or, where fx was estimated, "58.8 (52-67)"."""
    text = f"{pose.distance_cm:.1f}"
    if pose.distance_range_cm is not None:
        low, high = pose.distance_range_cm
        text += f" ({low:.0f}-{high:.0f})"
    return text


def _cell_table(predictions: list[Prediction]) -> Table:
    grids = sorted({p.cell.grid for p in predictions if p.cell is not None})
    table = Table(title=f"finer regions, grid {', '.join(grids)}")
    for name in ("file", "cell", "region", "p", "neighbours (cell p)"):
        table.add_column(name, justify="right" if name in ("cell", "p") else "left")
    for p in predictions:
        if p.cell is None:
            table.add_row(p.filename or "-", "-", "-", "-", "-")
            continue
        near = ", ".join(f"{n.index} {n.probability:.0%}" for n in p.cell.neighbours) or "-"
        table.add_row(
            p.filename or "-",
            str(p.cell.index),
            p.cell.label,
            f"{p.cell.probability:.0%}",
            near,
        )
    return table


def _models_table(listing: ModelList) -> Table:
    table = Table(title=f"{len(listing.models)} model(s), default {listing.default}")
    # the name is what `--model` takes: whole on one line (the title names the default)
    longest = max([len(m.name) for m in listing.models] + [len(n) for n in listing.problems])
    table.add_column("name", no_wrap=True, min_width=longest)
    for name in ("input", "object", "training", "right"):
        table.add_column(name)
    for m in listing.models:
        size, known = f"{m.input[0]}x{m.input[1]}", m.training or "-"
        table.add_row(m.name, size, m.profile or "-", known, _measured(m.accuracy))
    for name, problem in listing.problems.items():
        table.add_row(name, "-", "-", "-", f"not loaded: {_short(problem)}")
    return table


def _measured(accuracy: dict[str, Any]) -> str:
    """A card's accuracies in one cell: right over all the images it measured ("-": none;
    `model` shows them per data set)."""
    cells = [a for a in accuracy.values() if isinstance(a, dict)]
    counted = [(a["accuracy"], a["count"]) for a in cells if {"accuracy", "count"} <= set(a)]
    images = sum(n for _, n in counted)
    if not images:
        return "-"
    return f"{100 * sum(p * n for p, n in counted) / images:.1f} %"


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


# --- watch: a video file or a camera through the live stream -------------------------------


class StreamModeChoice(StrEnum):
    whole = "whole"
    sliding = "sliding"
    proposals = "proposals"


@app.command()
def watch(
    source: Annotated[
        str,
        typer.Argument(
            metavar="VIDEO_FILE_OR_CAMERA_INDEX",
            help="A video file (anything OpenCV reads: MP4, AVI, ...) or a camera index (0, 1..).",
        ),
    ],
    mode: Annotated[
        StreamModeChoice, typer.Option("--mode", help="whole, sliding or proposals.")
    ] = StreamModeChoice.whole,
    smooth: Annotated[
        float,
        typer.Option(
            "--smooth",
            min=0.0,
            max=0.99,
            help="Smoothing factor of the probabilities over frames, 0 = off (see docs/live.md).",
        ),
    ] = 0.0,
    out: Annotated[
        Path | None,
        typer.Option(
            "--out",
            help="Write the answered frames with the region drawn (MP4).",
            show_default=False,
        ),
    ] = None,
    max_frames: Annotated[
        int | None, typer.Option("--max-frames", min=1, help="Stop after this many frames.")
    ] = None,
    model: Annotated[
        str | None, typer.Option("--model", help="Model name (default: the service's).")
    ] = None,
    camera: CameraOption = None,
    fx: Annotated[
        float | None,
        typer.Option(
            "--fx",
            min=0.001,
            help="The camera's focal length in pixels of the frames, if known (else --camera, "
            "else the stream learns it).",
            show_default=False,
        ),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="One JSON answer per line.")] = False,
    url: UrlOption = DEFAULT_URL,
    api_key: KeyOption = None,
    timeout: TimeoutOption = 30.0,
) -> None:
    """Stream a video file or a camera through /v1/stream: one line per frame (region,
    confidence, fps, and the camera's pose where the model gives one); Ctrl-C stops (and
    keeps what --out has written)."""
    if fx is not None and camera is not None:
        _usage_error("give --fx or --camera, not both (the camera has its own fx)")
    with _errors_as_exit_codes():
        video = _open_video(source)
        try:
            summary = _watch(
                video,
                mode.value,
                smooth,
                out,
                max_frames,
                model,
                as_json,
                PoseClient(url, api_key, timeout=timeout),
                fx=fx,
                camera=camera,
            )
        finally:
            video.capture.release()
    typer.echo(summary.line(), err=as_json)
    if summary.errors:
        raise typer.Exit(ExitCode.BAD_INPUT)


class _Video:
    """An opened OpenCV capture: a file (every frame answered) or a camera (live: the service
    may drop frames)."""

    def __init__(self, capture: Any, name: str, live: bool) -> None:
        self.capture, self.name, self.live = capture, name, live
        fps = float(capture.get(5))  # cv2.CAP_PROP_FPS
        self.fps = fps if 0 < fps < 1000 else 30.0


def _cv2() -> Any:
    try:
        import cv2
    except ImportError:
        raise OSError("watch needs OpenCV: pip install 'planar-pose-client[video]'") from None
    return cv2


def _open_video(source: str) -> _Video:
    """Open camera `source` (digits) or video file `source`; OSError/ValueError otherwise."""
    cv2 = _cv2()
    if source.isdigit():
        capture = cv2.VideoCapture(int(source))
        if not capture.isOpened():
            raise OSError(f"camera {source} does not open (no such camera, or it is busy)")
        return _Video(capture, f"camera {source}", live=True)
    path = Path(source)
    if not path.exists():
        raise FileNotFoundError(f"no such video file: {path}")
    if path.is_dir():
        raise IsADirectoryError(f"is a directory, not a video file: {path}")
    capture = cv2.VideoCapture(str(path))
    if not capture.isOpened():
        raise ValueError(f"{path}: not a video OpenCV can read")
    return _Video(capture, str(path), live=False)


class _Summary:
    def __init__(self) -> None:
        self.answered = self.dropped = self.errors = 0
        self.seconds = 0.0

    def line(self) -> str:
        fps = self.answered / self.seconds if self.seconds > 0 else 0.0
        return (
            f"{self.answered} frame(s) answered, {self.dropped} dropped, {self.errors} refused, "
            f"{fps:.1f} frames/s"
        )


def _frames(video: _Video, kept: dict[int, Any] | None, limit: int | None) -> Iterator[bytes]:
    """JPEG bytes of each frame read; the decoded frame kept by index when `kept` is given."""
    cv2 = _cv2()
    index = 0
    while limit is None or index < limit:
        ok, bgr = video.capture.read()
        if not ok:
            if index == 0:
                raise ValueError(f"{video.name}: no frame could be read")
            return
        ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, 90])
        if not ok:
            raise ValueError(f"{video.name}: frame {index} could not be encoded as JPEG")
        if kept is not None:
            kept[index] = bgr
        yield bytes(buf.tobytes())
        index += 1


def _watch(
    video: _Video,
    mode: StreamMode,
    smooth: float,
    out: Path | None,
    max_frames: int | None,
    model: str | None,
    as_json: bool,
    client: PoseClient,
    *,
    fx: float | None = None,
    camera: str | None = None,
) -> _Summary:
    """Stream the frames, print a line per answer, write `out`; return the counts."""
    import time
    from collections import deque

    kept: dict[int, Any] | None = {} if out is not None else None
    writer, summary = None, _Summary()
    times: deque[float] = deque(maxlen=30)
    start = time.perf_counter()
    frames = _frames(video, kept, max_frames)
    window = None if video.live else DEFAULT_WINDOW
    try:
        with client:
            for item in client.stream(frames, mode, smooth, model, window, fx=fx, camera=camera):
                times.append(time.perf_counter())
                fps = (len(times) - 1) / (times[-1] - times[0]) if len(times) > 1 else 0.0
                summary.dropped += item.dropped
                typer.echo(item.model_dump_json() if as_json else _frame_line(item, fps))
                if isinstance(item, FrameError):
                    summary.errors += 1
                    continue
                summary.answered += 1
                if kept is not None and out is not None:
                    frame = _pop_frame(kept, item.seq)
                    writer = writer or _writer(out, video.fps, frame)
                    writer.write(_draw(frame, item))
    except KeyboardInterrupt:
        pass
    finally:
        summary.seconds = time.perf_counter() - start
        if writer is not None:
            writer.release()
    return summary


def _frame_line(item: StreamItem, fps: float) -> str:
    if isinstance(item, FrameError):
        return f"frame {item.seq:5d}  error: {item.code}: {item.message}"
    line = f"frame {item.seq:5d}  {item.label:<20}  {item.confidence:6.1%}  {fps:7.1f} fps"
    if item.pose is not None:
        line += f"  {_pose_words(item.pose)}"
    if item.cell is not None:
        line += f"  cell {item.cell.index} ({item.cell.probability:.0%})"
    return line + (f"  (dropped {item.dropped})" if item.dropped else "")


def _pose_words(pose: Pose) -> str:
    """e.g. "d 58.8 cm  az -68  el 56  fx 1480 (stream)"."""
    return (
        f"d {pose.distance_cm:.1f} cm  az {pose.azimuth_deg:.0f}  el {pose.elevation_deg:.0f}"
        f"  fx {pose.fx:.0f} ({pose.fx_source})"
    )


def _pop_frame(kept: dict[int, Any], seq: int) -> Any:
    """The frame of answer `seq`; frames before it (dropped by the service) are forgotten."""
    for old in [k for k in kept if k < seq]:
        del kept[old]
    return kept.pop(seq)


def _writer(out: Path, fps: float, frame: Any) -> Any:
    cv2 = _cv2()
    height, width = frame.shape[:2]
    writer = cv2.VideoWriter(str(out), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
    if not writer.isOpened():
        raise OSError(f"cannot write the video {out} (is the folder there and writable?)")
    return writer


def _draw(frame: Any, item: StreamPrediction) -> Any:
    """The frame with the best window (if any) and the region in words drawn on it."""
    cv2 = _cv2()
    if item.box is not None:
        b = item.box
        cv2.rectangle(frame, (b.x, b.y), (b.x + b.w, b.y + b.h), (40, 40, 230), 3)
    lines = [f"{item.label}  {item.confidence:.0%}"]
    if item.pose is not None:
        lines.append(_pose_words(item.pose))
    font, scale = cv2.FONT_HERSHEY_SIMPLEX, 0.7
    sizes = [cv2.getTextSize(text, font, scale, 2) for text in lines]
    step = max(th + base for (_, th), base in sizes) + 10
    width = max(tw for (tw, _), _ in sizes)
    cv2.rectangle(frame, (0, 0), (width + 16, step * len(lines) + 4), (0, 0, 0), -1)
    for i, text in enumerate(lines):
        baseline_y = step * i + sizes[i][0][1] + 8
        cv2.putText(frame, text, (8, baseline_y), font, scale, (255, 255, 255), 2, cv2.LINE_AA)
    return frame
