"""Training: loss goes down, a seed gives the same weights, resume continues exactly."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

import train.network.fit as fit_module
from service.core.paths import REPO_ROOT
from train.cli import app
from train.network.config import ConfigError, load_config
from train.network.fit import (
    Augmenter,
    FitConfig,
    TrainingError,
    evaluate_split,
    fit,
    load_network,
    load_split,
    to_input,
)
from train.network.model import PoseNet

runner = CliRunner()


def _config(data: Path, out: Path, **kw) -> FitConfig:
    base = {"epochs": 2, "batch_size": 8, "lr": 0.002, "progress": False, "threads": 1}
    return FitConfig(datasets=[data], out=out, **(base | kw))


def _weights(path: Path) -> dict[str, torch.Tensor]:
    return load_network(path)[0].state_dict()


@pytest.mark.parametrize("bf16", [False, True])
def test_training_reduces_the_loss(tiny_set, tmp_path, bf16):
    """Also with bfloat16 steps (`bf16`), whose weights stay float32."""
    train, _ = load_split([tiny_set], "train")
    torch.manual_seed(0)
    before, _ = evaluate_split(PoseNet((80, 60)), train)
    config = _config(tiny_set, tmp_path, epochs=3, augment=False, schedule="constant", bf16=bf16)
    summary = fit(config)
    net, checkpoint = load_network(tmp_path / "last.pt")
    after, _ = evaluate_split(net, train)
    assert after < 0.95 * before
    assert all(v.dtype == torch.float32 for v in net.state_dict().values() if v.is_floating_point())
    assert checkpoint["config"]["bf16"] is bf16
    rows = [json.loads(line) for line in (tmp_path / "log.jsonl").read_text().splitlines()]
    assert [r["epoch"] for r in rows] == [1, 2, 3]
    assert {"train_loss", "train_accuracy", "val_loss", "val_accuracy", "lr"} <= set(rows[0])
    assert summary["best"]["epoch"] in (1, 2, 3)
    assert (tmp_path / "best.pt").is_file()


def test_same_seed_same_weights(tiny_set, tmp_path):
    fit(_config(tiny_set, tmp_path / "a", seed=5))
    fit(_config(tiny_set, tmp_path / "b", seed=5))
    fit(_config(tiny_set, tmp_path / "c", seed=6))
    a, b, c = (_weights(tmp_path / r / "last.pt") for r in "abc")
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert not all(torch.equal(a[k], c[k]) for k in a)


def test_resume_after_an_interruption_ends_like_an_uninterrupted_run(
    tiny_set, tmp_path, monkeypatch
):
    fit(_config(tiny_set, tmp_path / "full", epochs=3))
    real_epoch = fit_module._train_epoch

    def interrupted(net, step, opt, train, pool, config, epoch, augmenter):
        if epoch == 3:
            raise KeyboardInterrupt
        return real_epoch(net, step, opt, train, pool, config, epoch, augmenter)

    monkeypatch.setattr(fit_module, "_train_epoch", interrupted)
    with pytest.raises(KeyboardInterrupt):
        fit(_config(tiny_set, tmp_path / "cut", epochs=3))
    monkeypatch.setattr(fit_module, "_train_epoch", real_epoch)
    summary = fit(_config(tiny_set, tmp_path / "cut", epochs=3), resume=True)
    assert summary["epochs_run"] == 3
    full, cut = _weights(tmp_path / "full" / "last.pt"), _weights(tmp_path / "cut" / "last.pt")
    assert all(torch.equal(full[k], cut[k]) for k in full)
    lines = (tmp_path / "cut" / "log.jsonl").read_text().splitlines()
    assert [json.loads(line)["epoch"] for line in lines] == [1, 2, 3]


def test_fine_tuning_starts_from_the_checkpoint(tiny_set, tmp_path):
    fit(_config(tiny_set, tmp_path / "base", epochs=1))
    base, _ = load_network(tmp_path / "base" / "best.pt")
    fit(_config(tiny_set, tmp_path / "ft", epochs=1, lr=0.0, init=tmp_path / "base" / "best.pt"))
    tuned, ckpt = load_network(tmp_path / "ft" / "last.pt")
    assert tuned.batch_norm and base.batch_norm
    # lr 0: the weights and the input normalisation stay; only the batch-norm running
    # statistics follow the new data.
    tuned_params = dict(tuned.named_parameters())
    assert all(torch.equal(v, tuned_params[k]) for k, v in base.named_parameters())
    assert torch.equal(base.mean, tuned.mean) and torch.equal(base.std, tuned.std)
    assert ckpt["parent"]["checkpoint"].endswith("best.pt")


def test_augmenter_keeps_shape_and_is_seeded():
    images = np.random.default_rng(0).integers(0, 256, (8, 60, 80, 3), dtype=np.uint8)
    aug = Augmenter((80, 60), p_blur=1.0, p_grey=0.5)
    corners = np.tile(np.array([10, 10, 70, 10, 70, 50, 10, 50], np.float32), (8, 1))
    a, ca = aug(images, np.zeros(8, int), np.random.default_rng(1), corners)
    b, cb = aug(images, np.zeros(8, int), np.random.default_rng(1), corners)
    assert a.shape == (8, 3, 60, 80) and a.dtype == torch.float32
    assert float(a.min()) >= 0.0 and float(a.max()) <= 1.0
    assert torch.equal(a, b) and not torch.equal(a, to_input(images)) and np.array_equal(ca, cb)
    c, _ = aug(images, np.zeros(8, int), np.random.default_rng(2), corners)
    assert not torch.equal(a, c)  # another seed, other crops, blur, gains and noise
    moved = np.any(ca != corners, axis=1)  # the cropped (zoomed-in) images
    width, height = ca[:, 2] - ca[:, 0], ca[:, 5] - ca[:, 3]
    assert moved.any() and np.all(width[moved] > 60) and np.all(height[moved] > 40)


def test_the_squash_crop_is_a_band_that_keeps_the_corners():
    """p_squash = 1: every crop is a full-width band of 0.7-1 of the height, stretched back
    to the height (a wide photo squashed to 4:3), with the object's corners inside it."""
    aug = Augmenter((80, 60), p_blur=0.0, p_grey=0.0, p_crop=1.0, p_squash=1.0)
    rng = np.random.default_rng(3)
    ramp = np.broadcast_to(np.arange(60, dtype=np.uint8)[:, None, None] * 4, (60, 80, 3))
    corners = np.array([20, 15, 60, 18, 58, 44, 22, 40], np.float32)
    for _ in range(20):
        out, moved = aug.crop(np.ascontiguousarray(ramp), corners, rng)
        assert np.array_equal(moved[0::2], corners[0::2])  # the width is kept
        stretch = (moved[5] - moved[3]) / (corners[5] - corners[3])
        assert 1.0 <= stretch <= 1 / 0.7 + 1e-6
        assert moved[1::2].min() >= -0.5 and moved[1::2].max() <= 59.5
        assert np.ptp(out[:, 40, 0].astype(int)) > 150  # rows from the top to the bottom band


def test_errors_are_clear(tiny_set, tmp_path):
    with pytest.raises(TrainingError, match="not a data set"):
        fit(_config(tmp_path / "missing", tmp_path / "run"))
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(TrainingError, match="not a readable PyTorch checkpoint"):
        load_network(bad)
    big = PoseNet((160, 120))
    torch.save(
        {"format": fit_module.CHECKPOINT_FORMAT, "size": [160, 120], "model": big.state_dict()},
        tmp_path / "big.pt",
    )
    with pytest.raises(TrainingError, match="takes 160x120 images but the data sets are 80x60"):
        fit(_config(tiny_set, tmp_path / "run", init=tmp_path / "big.pt"))
    fit(_config(tiny_set, tmp_path / "bn", epochs=1))
    with pytest.raises(TrainingError, match="trained with --batch-norm: resume with the same"):
        fit(_config(tiny_set, tmp_path / "bn", epochs=2, batch_norm=False), resume=True)


def test_cli_errors_exit_nonzero_with_a_message(tiny_set, tmp_path):
    result = runner.invoke(app, ["train", str(tmp_path / "nope"), "--out", str(tmp_path / "r")])
    assert result.exit_code == 1 and "data set not found" in result.output
    args = ["train", str(tiny_set), "--out", str(tmp_path / "r"), "--resume"]
    result = runner.invoke(app, args)
    assert result.exit_code == 1 and "no checkpoint" in result.output
    args = ["train", str(tiny_set), "--out", str(tmp_path / "r"), "--init", str(tmp_path / "x.pt")]
    result = runner.invoke(app, args)
    assert result.exit_code == 1 and "--init checkpoint not found" in result.output
    args = ["train", str(tiny_set), "--out", str(tmp_path / "r"), "--optimizer", "rmsprop"]
    result = runner.invoke(app, [*args, "--epochs", "1"])
    assert result.exit_code == 2 and "'rmsprop' is not one of" in result.output


def test_recipe_file_then_command_line(tiny_set, tmp_path):
    recipe = tmp_path / "r.toml"
    recipe.write_text(
        f'datasets = ["{tiny_set}"]\nout = "{tmp_path / "run"}"\nepochs = 5\n'
        'arch = "convnet"\nbatch_size = 8\nlr = 0.01\n'
    )
    config = load_config(recipe, {"epochs": 1, "lr": None})
    assert (config.epochs, config.lr, config.arch, config.batch_size) == (1, 0.01, "convnet", 8)
    assert config.datasets == [tiny_set] and config.optimizer == "sgd"  # FitConfig's default
    result = runner.invoke(app, ["train", "--config", str(recipe), "--epochs", "1"])
    assert result.exit_code == 0, result.output
    assert json.loads((tmp_path / "run" / "log.jsonl").read_text().splitlines()[-1])["epoch"] == 1


@pytest.mark.parametrize(
    "text,message",
    [
        ('epoch = 3\ndatasets = ["x"]\nout = "o"', "unknown option(s) epoch"),
        ('datasets = ["x"]\nout = "o"\noptimizer = "rmsprop"', "option optimizer"),
        ('datasets = ["x"]\nout = "o"\nepochs = 0', "option epochs must be in [1"),
        ('datasets = ["x", "y"]\nout = "o"\nrepeat = [1]', "repeat has 1 value(s) for 2"),
        ('out = "o"', "no data sets given"),
        ("epochs = [", "not valid TOML"),
    ],
)
def test_bad_recipes(tmp_path, text, message):
    recipe = tmp_path / "bad.toml"
    recipe.write_text(text)
    with pytest.raises(ConfigError, match=re.escape(message)):
        load_config(recipe, {})
    result = runner.invoke(app, ["train", "--config", str(recipe)])
    assert result.exit_code == 2 and message in result.output


@pytest.mark.parametrize(
    "recipe", sorted((REPO_ROOT / "recipes").glob("*.toml")), ids=lambda p: p.stem
)
def test_shipped_recipes_are_valid_configs(recipe):
    config = load_config(recipe, {})
    # the chessboard's recipes run under runs/default (scripts/train_default.sh), another
    # object's under runs/<object> (or a later run's runs/<object>2, ...): one run folder
    root = "default" if recipe.stem.startswith("chessboard") else recipe.stem.split("-")[0]
    run = config.out.parts[1]
    assert config.datasets and config.out.parts[::2] == ("runs", "runs")
    assert run == root or (run.startswith(root) and run[len(root) :].isdigit())
    assert all(p.parts[:3] == ("runs", run, "data") for p in [*config.datasets, *config.select])


def test_the_training_device(tiny_set, tmp_path):
    """auto is CUDA where torch sees a GPU and the CPU otherwise; asking for a GPU that is not
    there is a clear error, not a crash in the first batch."""
    import torch

    from train.network.fit import training_device

    expected = "cuda" if torch.cuda.is_available() else "cpu"
    assert training_device("auto").type == expected
    if not torch.cuda.is_available():
        with pytest.raises(TrainingError, match="no CUDA GPU"):
            fit(FitConfig(datasets=[tiny_set], out=tmp_path / "gpu", epochs=1, device="cuda"))
    summary = fit(FitConfig(datasets=[tiny_set], out=tmp_path / "cpu", epochs=1, device="cpu"))
    assert summary["epochs_run"] == 1
