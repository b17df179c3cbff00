"""Domain randomisation: the spec's ``[randomize]`` table and each frame's draws.

Every frame's draws are a pure function of (seed, class, instance, path index)
and the key drawn, so they are the same whatever shard, worker, executor or
renderer renders the frame, and a resumed run draws them again identically.
Each key has its own stream: enabling one key does not change another's draws.
The renderers consume a :class:`FrameDraws`; a spec without ``[randomize]``
gets the draws its ``[lighting]`` and ``[image]`` describe (frame_draws).
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np

from spm_data.errors import SpecError
from spm_data.core.poses import CV_TO_GL, intrinsics_from_fov

BACKGROUND_KINDS = ("black", "color", "gradient", "checker", "noise", "images")
RANGE_KEYS = ("lights", "light_strength", "light_color", "ambient", "base_color", "roughness", "metallic", "focal")
DEFAULT_ROUGHNESS, DEFAULT_METALLIC = 0.9, 0.0
MAX_LIGHTS = 8


@dataclass(frozen=True)
class RandomizeSpec:
    """``[randomize]``: each range is ``[low, high]``, drawn uniformly per frame; an
    absent key keeps the spec's fixed value."""

    lights: tuple[float, ...] = ()          # light count, integers [min, max]
    light_cone: float = 60.0                # degrees: directions uniform in this cone around the view axis
    light_strength: tuple[float, ...] = ()  # per light
    light_color: tuple[float, ...] = ()     # per light and channel, 0..1
    ambient: tuple[float, ...] = ()         # 0..1 of white
    base_color: tuple[float, ...] = ()      # factor on the texture, per channel
    roughness: tuple[float, ...] = ()       # 0..1
    metallic: tuple[float, ...] = ()        # 0..1
    backgrounds: tuple[str, ...] = ()       # kinds drawn from per frame (BACKGROUND_KINDS)
    focal: tuple[float, ...] = ()           # factor on fx and fy
    principal_point: float = 0.0            # pixels: cx and cy each uniform in +- this

    @property
    def enabled(self) -> bool:
        return self != RandomizeSpec()


@dataclass(frozen=True, eq=False)
class FrameDraws:
    """What a renderer sets for one frame besides the camera pose.

    K (3, 3) float64, OpenCV pixel centres; light_rotations (L, 3, 3) float64,
    each light's rotation in the camera's OpenGL frame (identity: a head light
    shining along the view axis; see light_directions); light_colors (L, 3)
    float64 0..1 linear; light_strengths (L,) float64 (pyrender lux-like,
    Blender sun strength); ambient 0..1; base_color (3,) float64 factor on the
    texture; roughness, metallic 0..1; background one of BACKGROUND_KINDS.
    """

    K: np.ndarray
    light_rotations: np.ndarray
    light_colors: np.ndarray
    light_strengths: np.ndarray
    ambient: float
    base_color: np.ndarray
    roughness: float
    metallic: float
    background: str

    def light_directions(self) -> np.ndarray:
        """(L, 3) float64 unit vectors in the OpenCV camera frame: where each light's rays travel."""
        return (self.light_rotations @ np.array([0.0, 0.0, -1.0])) @ CV_TO_GL

    def labels(self, max_lights: int) -> dict:
        """The shard's per-frame randomisation fields: lights (max_lights, 7) float32
        (direction 3, colour 3, strength; zero rows for lights not drawn), material
        (5,) float32 (base colour factor 3, roughness, metallic), ambient () float32,
        background: the frame's background kind (str)."""
        lights = np.zeros((max_lights, 7), np.float32)
        n = len(self.light_strengths)
        lights[:n, :3] = self.light_directions()
        lights[:n, 3:6] = self.light_colors
        lights[:n, 6] = self.light_strengths
        material = np.array([*self.base_color, self.roughness, self.metallic], np.float32)
        return {"lights": lights, "material": material, "ambient": np.float32(self.ambient),
                "background": str(self.background)}


def cone_rotations(tilts, azimuths) -> np.ndarray:
    """(L, 3, 3) rotations tilting the view axis by ``tilts`` (L,) radians towards
    the image directions ``azimuths`` (L,) radians (Rodrigues about an in-plane
    axis); a zero tilt is the identity."""
    out = np.empty((len(tilts), 3, 3))
    for i, (angle, phi) in enumerate(zip(tilts, azimuths)):
        if angle == 0:
            out[i] = np.eye(3)
            continue
        axis = np.array([np.cos(phi), np.sin(phi), 0.0])
        k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        out[i] = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k
    return out


def fixed_light_rotations(count: int) -> np.ndarray:
    """(count, 3, 3): the spec's fixed lights, which move with the camera: a head
    light and the others on a 40-degree cone around it, evenly spaced."""
    phis = [0.0] + [2 * np.pi * (i - 1) / max(count - 1, 1) for i in range(1, count)]
    return cone_rotations([0.0] + [np.radians(40.0)] * (count - 1), phis[:count]) if count else np.zeros((0, 3, 3))


# A frame's named random streams. Each number is part of every shard's bytes (the same seed gives
# the same pixels), so a stream keeps its number for good; a new stream takes a new one.
STREAMS = {"background": 1, "draws": 2}


def frame_rng(spec, instance: int, path_index: int, stream: str, key: str | None = None) -> np.random.Generator:
    """The generator of one frame's ``stream`` (STREAMS; "draws": one per ``key`` of [randomize] and
    the distractors): independent of shard layout, worker and every other frame and stream."""
    entropy = [int(spec.seed), zlib.crc32(spec.class_name.encode()), int(instance), int(path_index), STREAMS[stream]]
    return np.random.default_rng(entropy + ([zlib.crc32(key.encode())] if key is not None else []))


def frame_stream(spec, instance: int, path_index: int, key: str) -> np.random.Generator:
    """The generator of one frame's draws of one key."""
    return frame_rng(spec, instance, path_index, "draws", key)


def _uniform(spec, rz, instance, path_index, key, size=None):
    lo, hi = getattr(rz, key)
    return frame_stream(spec, instance, path_index, key).uniform(lo, hi, size)


def frame_draws(spec, instance: int, path_index: int, K=None) -> FrameDraws:
    """The draws of frame (``instance``, ``path_index``) of ``spec``; ``K`` (3, 3)
    the frame's unjittered intrinsics (default: the spec's)."""
    rz, li = spec.randomize, spec.lighting
    K = intrinsics_from_fov(spec.image.fov, spec.image.width, spec.image.height) if K is None else K
    args = (spec, rz, instance, path_index)
    if rz.lights:
        count = int(frame_stream(spec, instance, path_index, "lights").integers(rz.lights[0], rz.lights[1] + 1))
        rng = frame_stream(spec, instance, path_index, "light_direction")
        cos_t = rng.uniform(np.cos(np.radians(rz.light_cone)), 1.0, count)  # uniform over the cone's solid angle
        rotations = cone_rotations(np.arccos(cos_t), rng.uniform(0.0, 2 * np.pi, count))
    else:
        count, rotations = li.lights, fixed_light_rotations(li.lights)
    colors = _uniform(*args, "light_color", (count, 3)) if rz.light_color else np.ones((count, 3))
    strengths = _uniform(*args, "light_strength", count) if rz.light_strength else np.full(count, li.strength)
    K = np.array(K, dtype=np.float64)
    if rz.focal:
        K[[0, 1], [0, 1]] *= _uniform(*args, "focal")
    if rz.principal_point:
        K[:2, 2] += frame_stream(spec, instance, path_index, "principal_point").uniform(
            -rz.principal_point, rz.principal_point, 2)
    kinds = rz.backgrounds
    background = (kinds[int(frame_stream(spec, instance, path_index, "backgrounds").integers(len(kinds)))]
                  if kinds else spec.background.kind)
    return FrameDraws(
        K=K, light_rotations=rotations, light_colors=colors, light_strengths=strengths,
        ambient=float(_uniform(*args, "ambient")) if rz.ambient else li.ambient,
        base_color=_uniform(*args, "base_color", 3) if rz.base_color else np.ones(3),
        roughness=float(_uniform(*args, "roughness")) if rz.roughness else DEFAULT_ROUGHNESS,
        metallic=float(_uniform(*args, "metallic")) if rz.metallic else DEFAULT_METALLIC,
        background=background)


def max_lights(spec) -> int:
    """The most lights any frame of ``spec`` has."""
    return int(spec.randomize.lights[1]) if spec.randomize.lights else spec.lighting.lights


def lights_width(spec) -> int:
    """The width L of the shard's ``lights`` field: max_lights, at least 1 (HDF5 has no
    zero-width chunks; a frame without lights has a zero row)."""
    return max(1, max_lights(spec))


_BOUNDS = {"light_strength": (0.0, None), "light_color": (0.0, 1.0), "ambient": (0.0, 1.0),
           "base_color": (0.0, None), "roughness": (0.0, 1.0), "metallic": (0.0, 1.0), "focal": (1e-3, None),
           "lights": (0, MAX_LIGHTS)}


def validate_randomize(rz: RandomizeSpec, background_folder: str) -> None:
    """SpecError naming the ``randomize.`` key for any bad value."""
    for key in RANGE_KEYS:
        values = getattr(rz, key)
        if not values:
            continue
        lo, hi = _BOUNDS[key]
        if len(values) != 2 or values[0] > values[1]:
            raise SpecError(f"randomize.{key}: expected [low, high] with low <= high, got {list(values)}")
        if values[0] < lo or (hi is not None and values[1] > hi):
            raise SpecError(f"randomize.{key}: values must be within [{lo:g}, {'inf' if hi is None else f'{hi:g}'}], "
                            f"got {list(values)}")
        if key == "lights" and any(v != int(v) for v in values):
            raise SpecError(f"randomize.lights: expected whole light counts [min, max], got {list(values)}")
    if not 0.0 <= rz.light_cone <= 90.0:
        raise SpecError(f"randomize.light_cone: expected degrees in 0..90, got {rz.light_cone}")
    if rz.principal_point < 0:
        raise SpecError(f"randomize.principal_point: expected pixels >= 0, got {rz.principal_point}")
    for kind in rz.backgrounds:
        if kind not in BACKGROUND_KINDS:
            raise SpecError(f"randomize.backgrounds: {kind!r} is not one of {', '.join(BACKGROUND_KINDS)}")
    if "images" in rz.backgrounds and not background_folder:
        raise SpecError("randomize.backgrounds: \"images\" needs background.folder")
