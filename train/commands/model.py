"""CLI of the model steps: `train`, `evaluate`, `export` and `realset` (real photos -> data set).

torch is imported inside the commands only (the service install has no torch).
"""

from __future__ import annotations

import dataclasses
import inspect
import json
import typing
from pathlib import Path
from typing import Annotated, Any

import typer

from service.core.inputs import SIZE_HELP
from train.commands.common import fail, guard, out, size_or_exit, split_or_exit
from train.markdown import written_by


def _default(f: dataclasses.Field[Any]) -> Any:
    return f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default


def _train_signature() -> inspect.Signature:
    """`train`'s parameters: data sets, --out, --config, --resume, then one option per
    `FitConfig` field (`CLI_FIELDS`), with its help, bounds and type; default None = not given
    (the recipe file or FitConfig's default applies)."""
    from train.network.config import CLI_FIELDS, FitConfig

    hints = typing.get_type_hints(FitConfig)
    fields = {f.name: f for f in dataclasses.fields(FitConfig)}
    kw = inspect.Parameter.KEYWORD_ONLY
    params = [
        inspect.Parameter("datasets", kw, default=None, annotation=Annotated[
            list[Path] | None, typer.Argument(help="Data set folder(s), same image size.")]),
        inspect.Parameter("out_dir", kw, default=None, annotation=Annotated[
            Path | None, typer.Option("--out", help="Run folder (checkpoints, log.jsonl).")]),
        inspect.Parameter("config", kw, default=None, annotation=Annotated[
            Path | None, typer.Option(help="Recipe TOML file of FitConfig fields (recipes/).")]),
        inspect.Parameter("resume", kw, default=False, annotation=Annotated[
            bool, typer.Option(help="Continue OUT/last.pt.")]),
    ]  # fmt: skip
    for name in CLI_FIELDS:
        meta = fields[name].metadata
        option = typer.Option(
            help=f"{meta['help']} (default: {_default(fields[name])})",
            min=meta.get("min"),
            max=meta.get("max"),
            show_default=False,
        )
        kind = hints[name] if "None" in str(hints[name]) else hints[name] | None
        params.append(inspect.Parameter(name, kw, default=None, annotation=Annotated[kind, option]))
    return inspect.Signature(params)


def train(**options: Any) -> None:
    """Train (or with --init fine-tune) the pose network on the train split; keep the best val.

    Options come from `--config recipes/NAME.toml` and the command line (which wins).
    """
    from train.network.config import load_config
    from train.network.export import repo_path
    from train.network.fit import fit

    recipe, resume = options.pop("config"), options.pop("resume")
    options["datasets"] = options.pop("datasets") or None
    options["out"] = options.pop("out_dir")
    config = guard(lambda: load_config(recipe, options), code=2)
    if recipe is not None:
        config.extra["recipe"] = repo_path(recipe)
    for path in config.datasets + config.select:
        if not path.is_dir():
            raise fail(f"data set not found: {path}")
    if config.init is not None and not config.init.is_file():
        raise fail(f"--init checkpoint not found: {config.init}")
    if resume and not (config.out / "last.pt").is_file():
        raise fail(f"--resume: no checkpoint {config.out / 'last.pt'} to continue")
    summary = guard(lambda: fit(config, resume=resume))
    best = summary["best"]
    out.print(
        f"[green]done[/]: {summary['epochs_run']} epochs, best epoch {best['epoch']} "
        f"(val accuracy {100 * best['val_accuracy']:.2f} %), "
        f"{summary['ms_per_image']:.2f} ms / image (forward + backward + augmentation); "
        f"best weights in {config.out / 'best.pt'}"
    )


train.__signature__ = _train_signature()  # type: ignore[attr-defined]


def evaluate(
    paths: Annotated[
        list[Path],
        typer.Argument(help="Model(s) (.onnx or .pt checkpoint) then data set folder(s)."),
    ],
    out_dir: Annotated[Path, typer.Option("--out", help="Folder for metrics.json and plots.")],
    split: Annotated[str, typer.Option(help="train, val, test or all.")] = "test",
    markdown: Annotated[
        Path | None, typer.Option(help="Markdown report path (default OUT/report.md).")
    ] = None,
    title: str = "Evaluation",
    note: Annotated[list[str] | None, typer.Option(help="Paragraph under the title.")] = None,
    same_size: Annotated[
        bool, typer.Option(help="Skip model / data set pairs of different image sizes.")
    ] = False,
) -> None:
    """Evaluate model(s) on data set(s): metrics.json, Markdown, plots (grid if several)."""
    from tqdm import tqdm

    from service.core.dataset import load_dataset
    from train.network.evaluate import evaluate_predictor, load_predictor
    from train.network.report import write_report

    chosen = split_or_exit(split)
    models = [p for p in paths if p.suffix in (".onnx", ".pt")]
    datasets = [p for p in paths if p not in models]
    if not models:
        raise fail("give at least one model (.onnx or .pt) before the data sets", code=2)
    if not datasets:
        raise fail("give at least one data set folder after the model(s)", code=2)
    for path in datasets:
        if not (path / "labels.csv").is_file():
            raise fail(f"not a data set (no labels.csv): {path}")

    def body() -> Path:
        loaded = {p: load_predictor(p) for p in models}
        names = {p: _model_name(p, info) for p, (_, _, info) in loaded.items()}
        results: dict[str, dict[str, dict[str, Any]]] = {names[p]: {} for p in models}
        for ds in datasets:
            data = load_dataset(ds, split=chosen)
            if len(data.labels) == 0:
                raise ValueError(f"{ds} has no images in split {split!r}")
            for model in models:
                predict, size = loaded[model][:2]
                if same_size and data.images.shape[1:3] != (size[1], size[0]):
                    continue
                with tqdm(total=len(data.labels), desc=f"{names[model]} on {ds.name}") as bar:
                    metrics = evaluate_predictor(predict, data, bar.update)
                results[names[model]][ds.name] = metrics
                tqdm.write(f"{names[model]} on {ds.name}: {100 * metrics['accuracy']:.2f} %")
        sources = {names[p]: str(p) for p in models} | {d.name: str(d) for d in datasets}
        notes = [f"Split: `{split}`. " + written_by("planar-pose evaluate")] + list(note or [])
        return write_report(results, out_dir, markdown, title, notes, sources)

    report = guard(body)
    out.print(f"[green]done[/]: {out_dir / 'metrics.json'}, {report}")


def _model_name(path: Path, info: dict[str, Any]) -> str:
    """Display name of a model: its card name, else the run folder / file stem."""
    if isinstance(info.get("name"), str):
        return info["name"]
    return path.parent.name if path.suffix == ".pt" else path.stem


def export(
    checkpoint: Annotated[
        Path,
        typer.Argument(
            help="A checkpoint written by train (best.pt), or a shipped .onnx to measure again."
        ),
    ],
    name: Annotated[str, typer.Option(help="Model name: writes OUT_DIR/NAME.onnx and .json.")],
    out_dir: Annotated[Path, typer.Option(help="Where to write the model.")] = Path("models"),
    eval_data: Annotated[
        list[Path] | None,
        typer.Option("--eval", help="Data set(s) whose accuracy goes in the card."),
    ] = None,
    split: Annotated[str, typer.Option(help="Split measured for the card.")] = "test",
    eval_val: Annotated[
        list[Path] | None,
        typer.Option(
            "--eval-val",
            help="Data set(s) whose val split's accuracy goes in the card (accuracy_val: the "
            "sources the model was selected on).",
        ),
    ] = None,
    version: str = "1.0.0",
    notes: Annotated[str, typer.Option(help="Free text for the card (how it was made).")] = "",
    regraph: Annotated[
        bool,
        typer.Option(
            help="With a corner .onnx: export its weights again in this version's graph "
            "form (the zoom pass's view input and pattern output), as --version."
        ),
    ] = False,
) -> None:
    """Export a checkpoint to ONNX (probabilities, dynamic batch) with its model card.

    Given an .onnx model instead, measure it again on --eval and rewrite its card's accuracy
    (with --regraph, its graph too); without --eval, write it under the new --name only.
    """
    import re

    from train.network.export import export as run_export
    from train.network.export import recard

    split_or_exit(split)
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]*", name):
        raise fail(f"--name {name!r}: use letters, digits, '.', '_' or '-'", code=2)
    if regraph and checkpoint.suffix != ".onnx":
        raise fail("--regraph takes a corner .onnx model", code=2)
    if not checkpoint.is_file():
        raise fail(f"checkpoint not found: {checkpoint}")
    for path in [*(eval_data or []), *(eval_val or [])]:
        if not (path / "labels.csv").is_file():
            raise fail(f"not a data set (no labels.csv): {path}")
    if checkpoint.suffix == ".onnx":
        if regraph and not eval_data:
            raise fail("a regraphed model is measured again: give --eval data set(s)", code=2)
        new_version = version if regraph else None
        path, card = guard(
            lambda: recard(
                checkpoint,
                name,
                out_dir,
                eval_data or [],
                split,
                notes or None,
                new_version,
                eval_val,
            )
        )
    else:
        path, card = guard(
            lambda: run_export(
                checkpoint, name, out_dir, eval_data, split, version, notes, eval_val
            )
        )
    out.print(f"[green]wrote[/] {path} ({path.stat().st_size / 1e6:.2f} MB) and {name}.json")
    if "renamed_from" in card and not eval_data:
        out.print(f"  renamed from {card['renamed_from']!r}; accuracies as measured before")
    for ds, acc in [*card["accuracy"].items(), *card.get("accuracy_val", {}).items()]:
        out.print(f"  {ds} ({acc['split']}, {acc['count']} images): {100 * acc['accuracy']:.2f} %")


def realset(
    source: Annotated[Path, typer.Argument(help="Folder of real photos with labels.csv.")],
    out_dir: Annotated[Path, typer.Argument(help="New data set folder.")],
    size: Annotated[int, typer.Option(help=SIZE_HELP)] = 1,
    blur: Annotated[int, typer.Option(help="SPEC blur level 0..3.")] = 0,
    profile: Annotated[str, typer.Option(help="Profile name or path (z split).")] = "chessboard",
    seed: Annotated[int, typer.Option(help="Seed of the train/val/test split.")] = 0,
) -> None:
    """Turn real photos with camera centres into a data set (split by stereo moment)."""
    from train.real.realset import build_real_dataset

    size_or_exit(size)
    if not 0 <= blur <= 3:
        raise fail(f"--blur must be in 0..3, got {blur}", code=2)
    if not (source / "labels.csv").is_file():
        raise fail(f"no labels.csv in {source}")
    manifest = guard(lambda: build_real_dataset(source, out_dir, size, blur, profile, seed))
    out.print(f"[green]wrote[/] {out_dir}: {json.dumps(manifest['counts'])}")


def card(
    model: Annotated[
        Path, typer.Argument(help="A model (.onnx); its card beside it (.json) is rewritten too.")
    ],
    recipe: Annotated[
        Path | None, typer.Option(help="The recipe file of its last stage (recipes/NAME.toml).")
    ] = None,
    rebuild: Annotated[
        list[str] | None,
        typer.Option(help="A command that makes the model again (repeat, in order)."),
    ] = None,
    role: Annotated[
        str | None,
        typer.Option(help="pick (the model to use for its object) or ablation (kept for a page)."),
    ] = None,
    use: Annotated[str | None, typer.Option(help="When to pick it, in a sentence.")] = None,
    notes: Annotated[str | None, typer.Option(help="Free text for the card.")] = None,
) -> None:
    """Rewrite a model's card (ONNX metadata and .json): provenance, role, notes; the graph
    and its accuracies unchanged."""
    from train.network.export import amend_card, repo_path

    if model.suffix != ".onnx" or not model.is_file():
        raise fail(f"not an ONNX model file: {model}")
    if recipe is not None and not recipe.is_file():
        raise fail(f"recipe not found: {recipe}")
    where = repo_path(recipe) if recipe is not None else None
    written = guard(lambda: amend_card(model, where, rebuild, role, use, notes))
    out.print(f"[green]wrote[/] {model} and {model.with_suffix('.json').name}")
    out.print(f"  recipe {written['training'].get('recipe')}, role {written.get('role')}")


def catalog(
    models_dir: Annotated[Path, typer.Argument(help="Folder of models and cards.")] = Path(
        "models"
    ),
) -> None:
    """Write MODELS_DIR/README.md from the model cards: each model, its recipe, accuracy."""
    from train.network.catalog import write_catalog

    if not models_dir.is_dir():
        raise fail(f"models folder not found: {models_dir}", code=2)
    out.print(f"[green]wrote[/] {guard(lambda: write_catalog(models_dir))}")


#: The model commands; `train.cli` merges them into the `planar-pose` app.
app = typer.Typer()
app.command()(train)
app.command()(evaluate)
app.command()(export)
app.command()(realset)
app.command()(card)
app.command()(catalog)
