"""Object profiles: what the renderer needs to know about one planar object (SPEC sections 2-5).

A profile is a folder (or any TOML file) holding a `profile.toml` and a front-on texture image.
`load_profile("chessboard")` finds `train/assets/profiles/chessboard/profile.toml`; a path to a
profile file or to its folder works too, so new objects need no code change. Format (every
length in cm, every angle in degrees; only `texture`, `width_cm` and `height_cm` are required):

    name = "chessboard"            # default: the folder name
    texture = "texture.png"        # relative to the profile file; covers the object rectangle
    width_cm = 25.0                # the texture's physical extent (x along the width)
    height_cm = 17.5               # (y along the height, towards the top of the texture)

    [regions]                      # SPEC sections 3-4
    z_split_cm = 60.0
    box_min_cm = [-36.86, -36.86, 10.68]
    box_max_cm = [36.86, 36.86, 92.40]

    [camera]
    roll_deg = [-5.0, 5.0]         # roll about the optical axis, uniform in this range
    focal_scale = [0.6, 1.1]       # fx, fy multiplied by a factor uniform in this range
    focal_prior = 0.8              # the focal length a photo without one is posed with where
                                   # its view cannot tell (x the SPEC camera's; 0.4-1.2)
    distortion_k1 = [-0.3, 0.0]    # radial lens distortion k1 (OpenCV model), uniform
    lattice_radii_cm = [...]       # hemispheres of the camera lattice (SPEC section 4)
    lattice_heights_cm = [...]     # their centres (0, 0, h)
    lattice_points = 400           # Fibonacci points per hemisphere

    [border]                       # rendered around the texture, not part of the object
    margin_cm = [0.3, 1.5]         # white margin width range
    margin_rgb = [236, 236, 230]
    frame_cm = [0.0, 0.6]          # outer frame width range (0 = no frame)
    frame_grey = [70, 170]         # frame grey level range

The object frame's origin is the centre of the texture rectangle; the border lies outside it.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from service.core.geometry import camera_lattice
from service.core.paths import ASSETS_DIR, repo_relative
from service.core.pose import FOCAL_BOUNDS, FOCAL_PRIOR, is_focal_prior
from service.core.regions import RegionGeometry, pose_class

PROFILES_DIR = ASSETS_DIR / "profiles"
PROFILE_FILE = "profile.toml"
#: The object of the shipped models and of the real corpus: a 10 x 7-square chessboard.
DEFAULT_PROFILE = "chessboard"


class ProfileError(ValueError):
    """A profile that cannot be found or read, or whose values make no sense."""


@dataclass(frozen=True)
class Border:
    """White margin and outer frame drawn around the texture (ranges in cm / grey levels)."""

    margin_cm: tuple[float, float] = (0.0, 0.0)
    margin_rgb: tuple[int, int, int] = (255, 255, 255)
    frame_cm: tuple[float, float] = (0.0, 0.0)
    frame_grey: tuple[int, int] = (100, 100)


@dataclass(frozen=True)
class Profile:
    """A planar object: texture, physical size, region geometry and rendering ranges.

    `texture` is the path of the front-on texture image (+x right, +y up) covering the
    `width_cm` x `height_cm` rectangle centred on the object origin. Ranges are (low, high).
    """

    name: str
    path: Path
    texture: Path
    width_cm: float
    height_cm: float
    geometry: RegionGeometry
    roll_deg: tuple[float, float] = (0.0, 0.0)
    focal_scale: tuple[float, float] = (1.0, 1.0)
    distortion_k1: tuple[float, float] = (0.0, 0.0)
    focal_prior: float = FOCAL_PRIOR
    lattice_radii_cm: tuple[float, ...] = (20.0, 35.0, 50.0, 65.0, 80.0, 95.0)
    lattice_heights_cm: tuple[float, ...] = (0.0, 15.0, 30.0)
    lattice_points: int = 400
    border: Border = Border()

    @property
    def roll_max_deg(self) -> float:
        """Largest absolute roll of the range (SPEC 5's roll_max), degrees."""
        return float(max(abs(self.roll_deg[0]), abs(self.roll_deg[1])))

    def texture_rgb(self) -> np.ndarray:
        """The texture as RGB uint8 [h, w, 3]; raises ProfileError if it cannot be read."""
        bgr = cv2.imread(str(self.texture), cv2.IMREAD_COLOR)
        if bgr is None:
            raise ProfileError(f"profile {self.name!r}: cannot read texture image {self.texture}")
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)

    def lattice(self) -> np.ndarray:
        """Camera centres (M, 3) cm: the profile's Fibonacci hemispheres inside its box."""
        return camera_lattice(
            self.geometry, self.lattice_radii_cm, self.lattice_heights_cm, self.lattice_points
        )

    def manifest_entry(self) -> dict[str, Any]:
        """What a data set manifest records about the profile (texture repo-relative)."""
        return {
            "name": self.name,
            "width_cm": self.width_cm,
            "height_cm": self.height_cm,
            "z_split_cm": self.geometry.z_split_cm,
            "texture": repo_relative(self.texture),
            "box_min_cm": list(self.geometry.box_min),
            "box_max_cm": list(self.geometry.box_max),
            "roll_deg": list(self.roll_deg),
            "focal_scale": list(self.focal_scale),
            "distortion_k1": list(self.distortion_k1),
            "focal_prior": self.focal_prior,
        }


def focal_prior_of(entry: dict[str, Any]) -> float:
    """The focal prior (x the SPEC camera's) of a data set manifest's profile entry
    (`Profile.manifest_entry`); the project's `FOCAL_PRIOR` for entries written before it."""
    return float(entry.get("focal_prior", FOCAL_PRIOR))


def available_profiles() -> list[str]:
    """Names of the profiles shipped under train/assets/profiles."""
    return sorted(p.parent.name for p in PROFILES_DIR.glob(f"*/{PROFILE_FILE}"))


def _resolve(name_or_path: str | Path) -> Path:
    candidate = Path(name_or_path)
    if candidate.is_dir():
        candidate = candidate / PROFILE_FILE
    if candidate.is_file():
        return candidate
    named = PROFILES_DIR / str(name_or_path) / PROFILE_FILE
    if named.is_file():
        return named
    known = ", ".join(available_profiles()) or "none"
    raise ProfileError(
        f"unknown profile {str(name_or_path)!r}: not a profile name (known: {known}) "
        f"nor a path to a {PROFILE_FILE} or a folder holding one"
    )


def _range(
    table: dict[str, Any], key: str, default: tuple[float, float], where: str
) -> tuple[float, float]:
    value = table.get(key, default)
    if (
        not isinstance(value, list | tuple)
        or len(value) != 2
        or not all(isinstance(v, int | float) for v in value)
        or value[0] > value[1]
    ):
        raise ProfileError(f"{where}: {key} must be a range [low, high] of numbers, got {value!r}")
    return float(value[0]), float(value[1])


def _positive(table: dict[str, Any], key: str, where: str) -> float:
    value = table.get(key)
    if not isinstance(value, int | float) or isinstance(value, bool) or not value > 0:
        raise ProfileError(f"{where}: {key} must be a positive number of cm, got {value!r}")
    return float(value)


def _focal_prior(camera: dict[str, Any], where: str) -> float:
    value = camera.get("focal_prior", FOCAL_PRIOR)
    if not is_focal_prior(value):
        lo, hi = FOCAL_BOUNDS
        raise ProfileError(
            f"{where}: focal_prior must be a number from {lo} to {hi} (x the SPEC camera's "
            f"focal length), got {value!r}"
        )
    return float(value)


def _triple(
    table: dict[str, Any], key: str, default: tuple[float, float, float], where: str
) -> tuple[float, float, float]:
    value = table.get(key, default)
    if not isinstance(value, list | tuple) or len(value) != 3:
        raise ProfileError(f"{where}: {key} must be a list of 3 numbers, got {value!r}")
    return float(value[0]), float(value[1]), float(value[2])


def _rgb(value: Any, where: str) -> tuple[int, int, int]:
    if not isinstance(value, list | tuple) or len(value) != 3:
        raise ProfileError(f"{where}: margin_rgb must be a list of 3 grey levels, got {value!r}")
    return int(value[0]), int(value[1]), int(value[2])


def _grey_range(value: tuple[float, float]) -> tuple[int, int]:
    return int(value[0]), int(value[1])


def load_profile(name_or_path: str | Path) -> Profile:
    """Load a profile by name (a folder under train/assets/profiles) or by path (file or folder).

    Raises ProfileError (a ValueError) with a precise message for an unknown profile, an
    unparsable file, a missing/unreadable texture or a bad size, range or box.
    """
    path = _resolve(name_or_path)
    where = str(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ProfileError(f"{where}: not a readable TOML profile ({exc})") from exc
    if "texture" not in data:
        raise ProfileError(f"{where}: missing the texture image path (texture = ...)")
    texture = (path.parent / str(data["texture"])).resolve()
    if not texture.is_file():
        raise ProfileError(f"{where}: texture image not found: {texture}")
    width, height = _positive(data, "width_cm", where), _positive(data, "height_cm", where)

    regions = data.get("regions", {})
    default = RegionGeometry()
    geometry = RegionGeometry(
        z_split_cm=float(regions.get("z_split_cm", default.z_split_cm)),
        box_min=_triple(regions, "box_min_cm", default.box_min, where),
        box_max=_triple(regions, "box_max_cm", default.box_max, where),
    )
    if any(lo >= hi for lo, hi in zip(geometry.box_min, geometry.box_max, strict=True)):
        raise ProfileError(f"{where}: camera box min {geometry.box_min} not below max")
    if geometry.box_min[2] <= 0:
        raise ProfileError(f"{where}: the camera box must lie in front of the object (z > 0)")

    camera = data.get("camera", {})
    border = data.get("border", {})
    profile = Profile(
        name=str(data.get("name", path.parent.name)),
        path=path,
        texture=texture,
        width_cm=width,
        height_cm=height,
        geometry=geometry,
        roll_deg=_range(camera, "roll_deg", (0.0, 0.0), where),
        focal_scale=_range(camera, "focal_scale", (1.0, 1.0), where),
        distortion_k1=_range(camera, "distortion_k1", (0.0, 0.0), where),
        focal_prior=_focal_prior(camera, where),
        lattice_radii_cm=tuple(
            float(r) for r in camera.get("lattice_radii_cm", Profile.lattice_radii_cm)
        ),
        lattice_heights_cm=tuple(
            float(h) for h in camera.get("lattice_heights_cm", Profile.lattice_heights_cm)
        ),
        lattice_points=int(camera.get("lattice_points", Profile.lattice_points)),
        border=Border(
            margin_cm=_range(border, "margin_cm", (0.0, 0.0), where),
            margin_rgb=_rgb(border.get("margin_rgb", (255, 255, 255)), where),
            frame_cm=_range(border, "frame_cm", (0.0, 0.0), where),
            frame_grey=_grey_range(_range(border, "frame_grey", (100, 100), where)),
        ),
    )
    if profile.focal_scale[0] <= 0:
        raise ProfileError(f"{where}: focal_scale must be positive, got {profile.focal_scale}")
    profile.texture_rgb()  # fail now, not in a worker, if the image cannot be decoded
    classes = _lattice_classes(profile)
    if len(classes) < 8:
        missing = sorted(set(range(1, 9)) - classes)
        raise ProfileError(
            f"{where}: the camera lattice has no point in class(es) {missing}; widen the box, "
            "the lattice radii/heights or move z_split_cm"
        )
    return profile


def _lattice_classes(profile: Profile) -> set[int]:
    return {int(k) for k in pose_class(profile.lattice(), profile.geometry.z_split_cm)}


#: The profile `write_profile` writes: hand-held objects seen by webcams and phones.
NEW_PROFILE = """\
# {name}: {width_cm:g} x {height_cm:g} cm, written by `planar-pose object new`. Format:
# service/core/profile.py. Edit the ranges to match how the object is seen.
name = "{name}"
texture = "texture.png"   # front-on, covering exactly the object ({width_px}x{height_px} px)
width_cm = {width_cm:g}
height_cm = {height_cm:g}

[regions]                 # SPEC sections 3-4
z_split_cm = {z_split_cm:g}
box_min_cm = [-36.86, -36.86, 10.68]
box_max_cm = [36.86, 36.86, 92.40]

[camera]
roll_deg = [-180.0, 180.0]      # hand-held: any roll about the optical axis
focal_scale = [0.35, 0.9]       # fx / width of webcams and phones, x the SPEC camera's
distortion_k1 = [-0.45, 0.1]
focal_prior = 0.8               # the fx a photo is posed with where its view cannot tell
lattice_radii_cm = [20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 90.0, 100.0]
lattice_heights_cm = [0.0, 10.0, 20.0, 30.0, 40.0]
lattice_points = 400

[border]                  # around the texture, not part of the object
margin_cm = [0.0, 1.0]
margin_rgb = [238, 238, 232]
frame_cm = [0.0, 0.6]
frame_grey = [40, 160]
"""


def write_profile(
    folder: Path,
    name: str,
    texture_rgb: np.ndarray,
    width_cm: float,
    height_cm: float,
    z_split_cm: float = RegionGeometry().z_split_cm,
) -> Profile:
    """Write `folder`/profile.toml (`NEW_PROFILE`) and texture.png for an object whose
    front-on texture RGB uint8 [h, w, 3] covers `width_cm` x `height_cm`; return it loaded
    (validated). ProfileError if the texture's aspect is not the size's (2 % tolerance)."""
    h, w = texture_rgb.shape[:2]
    if not width_cm > 0 or not height_cm > 0:
        raise ProfileError(f"the size must be positive, got {width_cm:g} x {height_cm:g} cm")
    if abs((w / h) / (width_cm / height_cm) - 1) > 0.02:
        raise ProfileError(
            f"the texture is {w}x{h} px (aspect {w / h:.3f}) but the object "
            f"{width_cm:g} x {height_cm:g} cm (aspect {width_cm / height_cm:.3f}): crop the "
            "image to the object or give its size"
        )
    folder.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(folder / "texture.png"), cv2.cvtColor(texture_rgb, cv2.COLOR_RGB2BGR))
    text = NEW_PROFILE.format(
        name=name, width_cm=width_cm, height_cm=height_cm, width_px=w, height_px=h,
        z_split_cm=z_split_cm,
    )  # fmt: skip
    (folder / PROFILE_FILE).write_text(text, encoding="utf-8")
    return load_profile(folder)
