"""Object profiles: loading by name or path, clear errors, roll measurement."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.core.geometry import look_at, roll_of_pose
from service.core.paths import ASSETS_DIR
from service.core.pose import FOCAL_PRIOR
from service.core.profile import PROFILES_DIR, ProfileError, load_profile
from service.core.regions import pose_class
from train.real.realset import measure_rolls

REAL = ASSETS_DIR / "real" / "chessboard-stereo"


def _copy_profile(tmp_path: Path, text: str | None = None) -> Path:
    folder = tmp_path / "obj"
    shutil.copytree(PROFILES_DIR / "chessboard", folder)
    if text is not None:
        (folder / "profile.toml").write_text(text)
    return folder


def test_default_profile():
    p = load_profile("chessboard")
    assert (p.width_cm, p.height_cm) == (25.0, 17.5)
    assert p.geometry.z_split_cm == 60.0
    assert p.geometry.box_min == (-36.86, -36.86, 10.68)
    assert p.geometry.box_max == (36.86, 36.86, 92.40)
    assert p.texture_rgb().shape == (140, 200, 3)
    entry = p.manifest_entry()
    assert entry["texture"] == "train/assets/profiles/chessboard/texture.png"
    assert {"name", "width_cm", "height_cm", "z_split_cm", "texture"} <= set(entry)


def test_lattice_inside_box_and_every_class():
    p = load_profile("chessboard")
    lattice = p.lattice()
    assert p.geometry.contains(lattice).all()
    counts = np.bincount(pose_class(lattice, p.geometry.z_split_cm), minlength=9)[1:]
    assert counts.min() >= 300  # enough distinct cameras per class


def test_load_by_folder_and_file(tmp_path):
    folder = _copy_profile(tmp_path)
    assert load_profile(folder).name == "chessboard"
    assert load_profile(folder / "profile.toml").texture == (folder / "texture.png").resolve()


def test_name_defaults_to_folder(tmp_path):
    folder = _copy_profile(tmp_path, 'texture = "texture.png"\nwidth_cm = 25\nheight_cm = 17.5\n')
    p = load_profile(folder)
    assert p.name == "obj" and p.roll_deg == (0.0, 0.0) and p.geometry.z_split_cm == 60.0
    assert p.focal_prior == FOCAL_PRIOR and p.manifest_entry()["focal_prior"] == FOCAL_PRIOR


def test_unknown_profile():
    with pytest.raises(ProfileError, match="unknown profile 'nope'.*chessboard"):
        load_profile("nope")


def test_unreadable_texture(tmp_path):
    folder = _copy_profile(tmp_path)
    (folder / "texture.png").write_bytes(b"not a png")
    with pytest.raises(ProfileError, match="cannot read texture"):
        load_profile(folder)
    (folder / "texture.png").unlink()
    with pytest.raises(ProfileError, match="texture image not found"):
        load_profile(folder)


@pytest.mark.parametrize(
    "body,message",
    [
        (
            'texture = "texture.png"\nwidth_cm = -3\nheight_cm = 17.5\n',
            "width_cm must be a positive",
        ),
        ('texture = "texture.png"\nwidth_cm = 25\n', "height_cm must be a positive"),
        ("width_cm = 25\nheight_cm = 17.5\n", "missing the texture"),
        (
            'texture = "texture.png"\nwidth_cm = 25\nheight_cm = 1\n[camera]\nroll_deg = [5, -5]\n',
            "roll_deg must be a range",
        ),
        (
            'texture = "texture.png"\nwidth_cm = 25\nheight_cm = 1\n[regions]\nz_split_cm = 500\n',
            r"no point in class\(es\) \[5, 6, 7, 8\]",
        ),
        ("texture = \n", "not a readable TOML"),
        (
            'texture = "texture.png"\nwidth_cm = 25\nheight_cm = 1\n[camera]\nfocal_prior = 3\n',
            r"focal_prior must be a number from 0.4 to 1.2",
        ),
        (
            'texture = "texture.png"\nwidth_cm = 25\nheight_cm = 1\n[camera]\nfocal_prior = "x"\n',
            r"focal_prior must be a number",
        ),
    ],
)
def test_bad_profiles(tmp_path, body, message):
    folder = _copy_profile(tmp_path, body)
    with pytest.raises(ProfileError, match=message):
        load_profile(folder)


@settings(max_examples=60, deadline=None)
@given(
    st.floats(-30, 30),
    st.floats(-30, 30),
    st.floats(11, 90),
    st.floats(-179.0, 179.0),
)
def test_roll_of_pose_inverts_look_at(x, y, z, roll):
    R = look_at(np.array([x, y, z]), np.zeros(3), np.radians(roll))
    assert roll_of_pose(R) == pytest.approx(roll, abs=1e-6)


def test_real_photos_are_hand_held_at_any_roll():
    rolls = measure_rolls(REAL / "labels.csv")
    assert len(rolls) == 26
    assert rolls.min() < -110 and rolls.max() > 170  # nearly every roll occurs
