"""The SPEC network: shapes, L2 pooling, normalisation buffers."""

from __future__ import annotations

import pytest
import torch

from train.model import L2Pool2d, PoseNet, channel_stats, check_size, feature_shape


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
