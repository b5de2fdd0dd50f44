"""The texture bank, the renders of many objects and the background check by matching."""

from __future__ import annotations

import numpy as np
import pytest

from train.synth.background import (
    BackgroundPool,
    TextureMatcher,
    shipped_backgrounds,
    shipped_names,
)
from train.synth.stream import TextureStream
from train.synth.textures import (
    ASPECT,
    HELD_OUT_PHOTOS,
    HELD_OUT_SEEDS,
    KINDS,
    TRAIN_SEED_BASE,
    TextureBank,
    held_out_textures,
    photo_sources,
    procedural_texture,
)

SIZE = (160, 120)


def test_procedural_texture_is_its_seed_and_keeps_its_aspect() -> None:
    a, b = procedural_texture(123), procedural_texture(123)
    assert np.array_equal(a.rgb, b.rgb) and a.source == b.source
    assert not np.array_equal(a.rgb, procedural_texture(124).rgb)
    for seed in range(40):
        t = procedural_texture(seed)
        h, w = t.rgb.shape[:2]
        assert abs(h / w - t.height_cm / t.width_cm) < 0.02
        assert ASPECT[0] - 0.01 <= min(h / w, w / h) <= 1.0
        assert t.rgb.std() > 0  # something drawn on it
    kinds = {procedural_texture(seed).source.split(":")[1] for seed in range(60)}
    assert kinds == set(KINDS)


def test_training_never_draws_a_held_out_texture() -> None:
    assert max(HELD_OUT_SEEDS) < TRAIN_SEED_BASE
    bank = TextureBank()
    assert not set(bank.photos) & set(HELD_OUT_PHOTOS)
    assert set(photo_sources(held_out=True)) == set(HELD_OUT_PHOTOS)
    rng = np.random.default_rng(0)
    for _ in range(60):
        t = bank.draw(rng)
        kind, _, rest = t.source.partition(":")
        if kind == "procedural":
            assert int(rest.split(":")[1]) >= TRAIN_SEED_BASE
        else:
            assert rest not in HELD_OUT_PHOTOS
    test = held_out_textures()
    assert len(test) == len(HELD_OUT_SEEDS) + len(HELD_OUT_PHOTOS)


def test_matching_finds_a_photo_and_its_crop_not_other_photos() -> None:
    names, images = shipped_names(), shipped_backgrounds()
    coffee = images[names.index("photos/coffee.jpg")]
    for texture in (coffee, coffee[40:250, 60:300]):
        matcher = TextureMatcher(texture)
        shown = [n for n, im in zip(names, images, strict=True) if matcher.shown_in(im)]
        assert shown == ["photos/coffee.jpg"]
    plain = TextureMatcher(procedural_texture(HELD_OUT_SEEDS[0]).rgb)
    assert not any(plain.shown_in(im) for im in images)


def test_pool_sample_avoids_the_sources_asked() -> None:
    sources = [np.full((120, 160, 3), v, np.uint8) for v in (10, 100, 200)]
    pool = BackgroundPool(SIZE, sources)
    rng = np.random.default_rng(1)
    seen = {int(pool.sample(rng, frozenset({1}))[0, 0, 0]) for _ in range(60)}
    assert seen == {10, 200}


@pytest.fixture(scope="module")
def stream() -> TextureStream:
    sources = [np.random.default_rng(i).integers(0, 255, (120, 160, 3), np.uint8) for i in range(3)]
    return TextureStream(SIZE, backgrounds=BackgroundPool(SIZE, sources), p_distractor=0.5)


def test_stream_batch_has_one_object_per_image(stream: TextureStream) -> None:
    batch = stream.batch(12, np.random.default_rng(3))
    assert batch.images.shape == (12, 120, 160, 3) and len(batch.textures) == 12
    absent = batch.classes == 0
    assert np.isnan(batch.corners[absent]).all() and np.isfinite(batch.corners[~absent]).all()
    again = stream.batch(12, np.random.default_rng(3))
    assert np.array_equal(batch.images, again.images)  # a batch is its generator's
    assert len({t.source for t in batch.textures}) > 6  # each its own object
