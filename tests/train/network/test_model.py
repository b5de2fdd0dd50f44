"""The SPEC network: shapes, L2 pooling, normalisation buffers."""

from __future__ import annotations

import pytest
import torch

from train.network.model import (
    L2Pool2d,
    PoseNet,
    channel_stats,
    check_size,
    feature_shape,
    fold_batch_norm,
)


@pytest.mark.parametrize(
    ("size", "flat", "hidden"), [((80, 60), 384, 128), ((160, 120), 3072, 1024)]
)
def test_layer_sizes_follow_the_spec_table(size, flat, hidden):
    net = PoseNet(size)
    fh, fw = feature_shape(size)
    assert 64 * fh * fw == flat
    assert net.classifier[1].in_features == flat
    assert net.classifier[1].out_features == hidden
    x = torch.rand(2, 3, size[1], size[0])
    feats = net.features(x)
    assert feats.shape == (2, 64, fh, fw)
    out = net(x)
    assert out.shape == (2, 9)
    torch.testing.assert_close(out.exp().sum(1), torch.ones(2))


def test_l2_pool_is_sqrt_of_window_sum_of_squares():
    x = torch.randn(3, 5, 17, 13)
    pooled = L2Pool2d(4)(x)
    torch.testing.assert_close(pooled, torch.nn.LPPool2d(2, 4)(x))
    window = x[1, 2, 4:8, 8:12]
    torch.testing.assert_close(pooled[1, 2, 1, 2], window.pow(2).sum().sqrt())
    assert pooled.shape == (3, 5, 4, 3)


def test_unsupported_size_is_refused():
    with pytest.raises(ValueError, match="unsupported input size 64x48"):
        check_size((64, 48))


def test_normalisation_lives_in_the_state_dict():
    images = torch.randint(0, 256, (4, 6, 8, 3), dtype=torch.uint8)
    mean, std = channel_stats(images, chunk=3)
    x = images.reshape(-1, 3).double() / 255
    torch.testing.assert_close(mean, x.mean(0).float())
    torch.testing.assert_close(std, x.std(0, unbiased=False).float())
    net = PoseNet((80, 60))
    net.set_normalisation(mean, std)
    other = PoseNet((80, 60))
    other.load_state_dict(net.state_dict())
    torch.testing.assert_close(other.mean.flatten(), mean)
    torch.testing.assert_close(other.std.flatten(), std)


def _trained_batch_norm_net(size: tuple[int, int]) -> PoseNet:
    """A batch-norm PoseNet whose norms are far from identity (random affine, real stats)."""
    torch.manual_seed(3)
    net = PoseNet(size, batch_norm=True)
    net.set_normalisation(torch.tensor([0.4, 0.5, 0.6]), torch.tensor([0.2, 0.25, 0.3]))
    with torch.no_grad():
        net.train()
        for _ in range(3):
            net(torch.rand(8, 3, size[1], size[0]))
        for module in net.modules():
            if isinstance(module, torch.nn.BatchNorm1d | torch.nn.BatchNorm2d):
                module.weight.uniform_(0.5, 1.5)
                module.bias.uniform_(-0.5, 0.5)
    return net.eval()


@pytest.mark.parametrize("size", [(80, 60), (160, 120)])
def test_folding_batch_norm_gives_the_plain_spec_network(size):
    net = _trained_batch_norm_net(size)
    plain = fold_batch_norm(net).eval()
    assert not plain.batch_norm
    assert set(plain.state_dict()) == set(PoseNet(size).state_dict())
    x = torch.rand(5, 3, size[1], size[0])
    with torch.no_grad():
        torch.testing.assert_close(plain.logits(x), net.logits(x), atol=1e-5, rtol=1e-5)


def test_folding_a_plain_network_copies_it():
    net = PoseNet((80, 60)).eval()
    plain = fold_batch_norm(net)
    assert plain is not net
    for key, value in net.state_dict().items():
        torch.testing.assert_close(plain.state_dict()[key], value)
