"""The generic corner network: starts as the CornerNet it is grown from, reads the picture,
trains and resumes, and becomes one object's network with a measured presence threshold."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from service.core.profile import load_profile
from train.commands.object import GENERIC_WEIGHTS as COMMAND_GENERIC
from train.network.anyfit import GenericConfig, train_generic
from train.network.anynet import AnyCornerNet, grown_from, texture_tensor
from train.network.corners import CornerNet
from train.network.fit import load_network
from train.network.model import arch_of
from train.network.zeroshot import (
    ABSENT_RIGHT,
    GENERIC_WEIGHTS,
    THRESHOLDS,
    load_generic,
    object_checkpoint,
    object_network,
    presence_threshold,
    save_generic,
)
from train.synth.background import BackgroundPool
from train.synth.stream import TextureStream

SIZE = (160, 120)


def test_grown_network_starts_as_its_parent_whatever_the_picture() -> None:
    torch.manual_seed(0)
    parent = CornerNet(SIZE, stride=2).eval()
    net = grown_from(parent, AnyCornerNet(SIZE)).eval()
    x = torch.rand(2, 3, 120, 160)
    xn = (x - net.mean) / net.std
    expected = parent._encode(xn)
    for seed in (1, 2):
        picture = torch.rand(1, 3, 64, 64, generator=torch.Generator().manual_seed(seed))
        got = net.encode_with(xn, picture, torch.ones(1))
        for a, b in zip(got, expected, strict=True):
            assert torch.allclose(a, b, atol=1e-5)
    # once its new layers are not zero, the picture changes the answer
    torch.nn.init.normal_(net.inject.weight)
    a = net.encode_with(xn, torch.zeros(1, 3, 64, 64), torch.ones(1))[0]
    b = net.encode_with(xn, torch.ones(1, 3, 64, 64), torch.ones(1))[0]
    assert not torch.allclose(a, b)


def test_texture_tensor_shape_and_range() -> None:
    t = texture_tensor(np.full((30, 50, 3), 255, np.uint8))
    assert t.shape == (3, 64, 64) and float(t.min()) == 1.0


def test_presence_threshold_separates_scores() -> None:
    score = np.array([0.1, 0.2, 0.25, 0.6, 0.7, 0.9])
    present = np.array([False, False, False, True, True, True])
    t, bias, rates = presence_threshold(score, np.full(6, 0.01), present)
    assert 0.25 < t <= 0.6 and rates == {"present_right": 1.0, "absent_right": 1.0}
    assert bias == -30.0  # a tie: the alignment score alone
    # a presence logit that says "present" everywhere is biased away
    t, bias, rates = presence_threshold(score, np.full(6, 0.99), present)
    assert rates["absent_right"] == 1.0 and bias < -4.0


def test_presence_threshold_keeps_absent_right_then_most_present() -> None:
    # overlapping scores (off the grid's values): the balanced best gives up absent renders
    absent, present_scores = np.linspace(0.103, 0.503, 40), np.linspace(0.303, 0.903, 40)
    score = np.concatenate([absent, present_scores])
    present = np.arange(80) >= 40
    t, bias, rates = presence_threshold(score, np.full(80, 0.01), present)
    assert rates["absent_right"] >= ABSENT_RIGHT and rates["absent_right"] == np.mean(absent < t)
    most = max(np.mean(present_scores > u) for u in THRESHOLDS if np.mean(absent < u) >= 0.97)
    assert rates["present_right"] == most < 1.0


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    sources = [np.random.default_rng(i).integers(0, 255, (120, 160, 3), np.uint8) for i in range(2)]
    stream = TextureStream(SIZE, backgrounds=BackgroundPool(SIZE, sources))
    out = tmp_path_factory.mktemp("any")
    config = GenericConfig(out, steps=2, batch_size=4, eval_every=1, val_count=6, threads=1)
    train_generic(config, say=lambda s: None, stream=stream)
    config.steps = 3  # run again: continues
    state = train_generic(config, say=lambda s: None, stream=stream)
    assert state["step"] == 3 and [r["step"] for r in state["history"]] == [1, 2, 3]
    return out


def test_generic_run_checkpoints_load_and_become_one_objects(run: Path, tmp_path: Path) -> None:
    net, saved = load_network(run / "best.pt")
    assert arch_of(net) == "corners-any" and saved["epoch"] >= 1
    save_generic(run / "best.pt", tmp_path / "g.npz")
    generic, card = load_generic(tmp_path / "g.npz")
    assert card["steps"] == saved["epoch"]
    rebuild = card["config"]["extra"]["rebuild"]  # a command that exists, with its start
    assert rebuild[0].startswith(f"python scripts/train_any.py {run} --steps 3 ")
    assert (Path(__file__).parents[3] / "scripts/train_any.py").is_file()
    start = card["initialised_from"]  # lineage: None where the run started from scratch
    assert rebuild[0].endswith("--init " + ("none" if start is None else start["onnx"]))
    book = load_profile("book")
    mine = object_network(book, generic)
    assert not torch.equal(mine.texture_input, generic.texture_input)  # the book's picture
    assert torch.equal(mine.heat.weight, generic.heat.weight)
    mine.presence_corr.fill_(0.3)
    path = object_checkpoint(mine, book, card, tmp_path / "book.pt")
    again, ck = load_network(path)
    assert isinstance(again, AnyCornerNet) and float(again.presence_corr) == pytest.approx(0.3)
    assert ck["profile"]["name"] == "book"
    x = torch.rand(2, 3, 120, 160)
    assert torch.allclose(again.eval()(x), mine.eval()(x), atol=1e-5)


def test_the_command_names_the_weights_the_network_reads() -> None:
    assert COMMAND_GENERIC == GENERIC_WEIGHTS


def test_top_order_loss_is_zero_for_any_roll_of_the_corners() -> None:
    from train.network.fit import _corner_loss

    corners = np.array([[10, 50, 100, 20, 120, 90, 20, 110]], np.float32)  # corner 1 highest
    unit = np.tile([2 / 160, 2 / 120], 4)
    top = torch.tensor(np.roll(corners, -2, 1) * unit - 1, dtype=torch.float32)
    assert float(_corner_loss(top, corners, 160, 120, 0.01, "top")) < 1e-9
    given = torch.tensor(corners * unit - 1, dtype=torch.float32)
    assert float(_corner_loss(given, corners, 160, 120, 0.01, "top")) > 0.1


def test_the_quarter_turn_is_read_from_the_texture() -> None:
    from train.synth.render import View, render_view

    book = load_profile("book")
    net = any_corner_net_for(book)
    centre, target = np.array([8.0, -12.0, 45.0]), np.array([1.0, 0.5, 0.0])
    image = render_view(book, SIZE, centre, target, roll_deg=20.0)
    truth = View(centre, target, 20.0).object_corners(book, SIZE)
    x = torch.from_numpy(image).permute(2, 0, 1)[None].float() / 255
    for k in (1, 2, 3):  # the heat maps' corners, turned by k quarters
        turned = torch.tensor(np.roll(truth, k, 0), dtype=torch.float32)[None]
        net._soft_argmax = lambda heat, offset, q=turned: q  # type: ignore[method-assign]
        corners = net.answer(x)[1][0].detach().numpy()
        assert np.abs(corners - truth).max() < 1.5, k


def any_corner_net_for(profile) -> AnyCornerNet:  # type: ignore[no-untyped-def]
    from train.network.model import any_corner_net

    return any_corner_net(SIZE, profile.manifest_entry()).eval()
