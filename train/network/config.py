"""The options of a training run, defined once: `FitConfig`.

`planar-pose train` derives its command-line options from these fields (help, bounds and
choices from each field's metadata and type), and `--config recipes/NAME.toml` reads the
same fields from a file; `load_config` merges defaults < file < command line and validates
the result (pydantic), so every option has one name, one type and one default.

No torch here: the CLI imports this module.
"""

from __future__ import annotations

import dataclasses
import tomllib
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

from pydantic import TypeAdapter, ValidationError

Optimizer = Literal["sgd", "adam"]
Schedule = Literal["cosine", "step", "constant"]
Arch = Literal["spec", "convnet", "corners-coarse", "corners", "corners-any"]
Device = Literal["auto", "cpu", "cuda"]
#: The corner networks (`train.network.corners`): heat maps at stride 4 (coarse) or 2, and
#: the generic one that reads the object's picture (`train.network.anynet`, stride 2).
CORNER_ARCHS = ("corners-coarse", "corners", "corners-any")
#: Names the corner networks had before 2026-12-05, still read in recipes and checkpoints.
LEGACY_ARCHS = {"keypoint": "corners-coarse", "keypoint-s2": "corners"}


def canonical_arch(name: str) -> str:
    """The architecture's current name (`LEGACY_ARCHS`), or `name` itself."""
    return LEGACY_ARCHS.get(name, name)


def _opt(default: Any, help: str, **bounds: Any) -> Any:
    meta = {"help": help, **bounds}
    if isinstance(default, list):
        return field(default_factory=lambda: list(default), metadata=meta)
    return field(default=default, metadata=meta)


@dataclass
class FitConfig:
    """Options of a training run. Paths are data set folders / checkpoint files."""

    datasets: list[Path]
    out: Path
    epochs: int = _opt(30, "Epochs.", min=1)
    batch_size: int = _opt(32, "Images per batch.", min=1)
    arch: Arch = _opt(
        "spec",
        "Network: spec (SPEC section 8), convnet (train.network.convnet), corners-coarse "
        "(train.network.corners, corner heat maps at stride 4), corners (heat maps at "
        "stride 2; with `init` a corners-coarse checkpoint, it starts from its weights) or "
        "corners-any (train.network.anynet: reads the object's picture; fine-tuned from the "
        "generic network).",
    )
    optimizer: Optimizer = _opt("sgd", "sgd (with momentum) or adam.")
    lr: float = _opt(0.001, "Learning rate.", min=0.0)
    momentum: float = _opt(0.9, "SGD momentum.", min=0.0, max=1.0)
    weight_decay: float = _opt(1e-4, "Weight decay.", min=0.0)
    schedule: Schedule = _opt("cosine", "cosine, step (x0.1 at 2/3 of the epochs) or constant.")
    patience: int = _opt(10, "Early stop after N epochs without improvement; 0 = never.", min=0)
    seed: int = _opt(0, "Seed of weights, batch order and augmentation.")
    augment: bool = _opt(True, "On-the-fly blur, crop and photometric augmentation.")
    squash: float = _opt(
        0.0,
        "Augmentation: probability that a crop is a band of 0.7-1 of the height, resized "
        "back: what a wide photo (16:9 and wider) squashed to the input size looks like.",
        min=0.0,
        max=1.0,
    )
    init: Path | None = _opt(
        None, "Checkpoint to start from (fine-tuning), or a shipped corner model's .onnx."
    )
    batch_norm: bool = _opt(True, "spec: train with batch norm, folded away on export.")
    threads: int = _opt(0, "Torch intra-op threads; 0 = torch default.", min=0)
    device: Device = _opt("auto", "Where to train: cpu, cuda, or auto (cuda where torch sees one).")
    compile: bool = _opt(False, "torch.compile the training step.")
    bf16: bool = _opt(
        False,
        "Forward and backward passes in bfloat16 (torch.autocast; weights, optimiser, loss and "
        "evaluation stay float32): on CPUs with AMX (Sapphire Rapids and later) the "
        "corner networks train 1.4-1.6x faster (docs/benchmarks.md); slower on CPUs "
        "without bfloat16 units.",
    )
    corner_weight: float = _opt(
        0.5, "convnet, corners: weight of the loss on the object's four image corners.", min=0.0
    )
    corner_beta: float = _opt(
        0.1, "Corner loss: smooth-L1 beta in [-1, 1] image units (quadratic below it).", min=1e-4
    )
    repeat: list[int] = _opt(
        [], "Times each data set's train split appears per epoch (one per data set; default 1)."
    )
    select: list[Path] = _opt(
        [], "Data sets whose val split picks the best epoch (default: all of them)."
    )
    progress: bool = True
    extra: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """JSON-ready copy (paths as strings)."""
        out = asdict(self)
        out["datasets"] = [str(p) for p in self.datasets]
        out["select"] = [str(p) for p in self.select]
        out["out"] = str(self.out)
        out["init"] = None if self.init is None else str(self.init)
        return out


#: Fields set on the command line as options (the others: positional data sets, --out).
CLI_FIELDS = tuple(
    f.name for f in dataclasses.fields(FitConfig) if "help" in f.metadata and f.name != "repeat"
)


class ConfigError(ValueError):
    """A recipe file or option value that does not fit FitConfig, with a precise message."""


def read_recipe(path: Path) -> dict[str, Any]:
    """A recipe TOML file -> its FitConfig fields (unknown keys are an error)."""
    if not path.is_file():
        raise ConfigError(f"recipe not found: {path}")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None
    known = {f.name for f in dataclasses.fields(FitConfig)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ConfigError(f"{path}: unknown option(s) {', '.join(unknown)}")
    return data


def load_config(recipe: Path | None, overrides: dict[str, Any]) -> FitConfig:
    """FitConfig from defaults < `recipe` file < `overrides` (None values are not given)."""
    values = read_recipe(recipe) if recipe is not None else {}
    values |= {k: v for k, v in overrides.items() if v is not None and v != []}
    if isinstance(values.get("arch"), str):
        values["arch"] = canonical_arch(values["arch"])
    for key in ("datasets", "out"):
        if not values.get(key):
            where = f" (not in {recipe} either)" if recipe else ""
            raise ConfigError(f"no {'data sets' if key == 'datasets' else '--out'} given{where}")
    try:
        config = TypeAdapter(FitConfig).validate_python(values)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"])
        raise ConfigError(f"option {where}: {first['msg']}") from None
    if config.repeat and len(config.repeat) != len(config.datasets):
        raise ConfigError(
            f"repeat has {len(config.repeat)} value(s) for {len(config.datasets)} data set(s)"
        )
    for f in dataclasses.fields(FitConfig):
        value, lo, hi = getattr(config, f.name), f.metadata.get("min"), f.metadata.get("max")
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise ConfigError(f"option {f.name} must be in [{lo}, {hi if hi is not None else '∞'}]")
    return config
