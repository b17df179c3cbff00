"""Camera paths: the views a spec renders, computed per frame index, never materialised.

``sampler = "grid"`` (the default, the paper's): an ordered walk over an azimuth x
elevation (x roll) x distance grid. The walk is serpentine (a reflected mixed-radix
Gray code): consecutive frames differ by exactly one step on exactly one angle axis,
so a path is a camera moving in 5 degree steps, as in the paper.

``sampler = "sphere"`` or ``"so3"``: ``views`` random views, view ``i`` drawn from
its own counter-based stream (seed, i), so any view is computed alone, the same on
every machine, in any order, resumed or not. ``sphere``: viewing directions uniform
on the sphere's zone between two elevations, roll uniform in a range; ``so3``:
uniform random rotations (directions over the whole sphere, roll over the full
circle). Distances uniform in a range. The pose convention is in poses.py.

This module holds what a spec says (:class:`CameraGrid`) and its checks; the walks
themselves (the paths' points per index) are in walks.py.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from spm_data.errors import SpecError
from spm_data.core.walks import AngleRange, CameraPath, SampledPath

_EPS = 1e-9


@dataclass(frozen=True)
class CameraGrid:
    """What a spec says about the camera path.

    distance_mode: ``"cycle"`` gives frame ``i`` the distance ``distances[i % n]``
    (views per instance = azimuths x elevations x rolls); ``"grid"`` repeats the
    whole angle walk at every distance (views x n).
    """

    azimuth: AngleRange = AngleRange(0.0, 355.0, 5.0)
    elevation: AngleRange = AngleRange(0.0, 60.0, 5.0)
    roll: AngleRange = AngleRange(0.0, 0.0, 5.0)
    distances: tuple[float, ...] = (0.6, 0.7, 0.8)
    distance_mode: str = "cycle"
    look_at: tuple[float, float, float] = (0.0, 0.0, 0.0)
    sampler: str = "grid"                                # "grid" | "sphere" | "so3"
    views: int = 0                                       # sphere, so3: views per instance
    elevation_range: tuple[float, ...] = (0.0, 60.0)     # sphere: degrees, lowest and highest
    roll_range: tuple[float, ...] = (0.0, 0.0)           # sphere: degrees
    distance_range: tuple[float, ...] = ()               # sphere, so3: metres; default min..max of distances

SAMPLERS = ("grid", "sphere", "so3")
SAMPLER_KEYS = ("sampler", "views", "elevation_range", "roll_range", "distance_range")  # unused by "grid"


def _check_range(values, key: str, lo=None, hi=None, positive=False) -> tuple[float, float]:
    """A [low, high] pair from a spec, checked: SpecError naming ``key``."""
    values = tuple(float(v) for v in values)
    if len(values) != 2 or not all(np.isfinite(values)) or values[0] > values[1]:
        raise SpecError(f"camera.{key}: expected [low, high] with low <= high, got {list(values)}")
    if (lo is not None and values[0] < lo - _EPS) or (hi is not None and values[1] > hi + _EPS) \
            or (positive and values[0] <= 0):
        bound = "> 0 metres" if positive else f"within [{lo:g}, {hi:g}] degrees"
        raise SpecError(f"camera.{key}: values must be {bound}, got {list(values)}")
    return values


def _check_distances(grid: CameraGrid) -> None:
    distances = np.asarray(grid.distances, dtype=np.float64)
    if distances.size == 0:
        raise SpecError("camera.distances: empty list; give at least one distance in metres")
    if np.any(~np.isfinite(distances)) or np.any(distances <= 0):
        raise SpecError(f"camera.distances: every distance must be a finite number > 0 metres, got "
                        f"{list(grid.distances)}")
    if grid.sampler == "grid" and len(set(distances.tolist())) < len(distances):
        raise SpecError(f"camera.distances: {list(grid.distances)} lists a distance twice, so views would repeat; "
                        "list each distance once")


def _check_full_turn(angles: AngleRange, key: str) -> None:
    """SpecError when an angle grid reaches a full turn: its first and last values (or more) are the
    same view, rendered twice (azimuth 0..360 repeats 0)."""
    n = angles.count(key)
    if n > 1 and angles.step * (n - 1) >= 360.0 - _EPS:
        last = angles.start + angles.step * math.floor((360.0 - _EPS) / angles.step)
        raise SpecError(f"{key}: {angles.start:g}..{angles.stop:g} reaches a full turn, so "
                        f"{angles.start:g} and {angles.start + 360:g} degrees are the same view, rendered twice; "
                        f"stop at {last:g}")


def sampled_path(grid: CameraGrid, seed: int = 0) -> SampledPath:
    """The random views of a ``"sphere"`` or ``"so3"`` spec (validated)."""
    if grid.views < 1:
        raise SpecError(f"camera.views: sampler {grid.sampler!r} needs views = N >= 1 (views per instance), "
                        f"got {grid.views}")
    _check_distances(grid)
    distance_range = grid.distance_range or (min(grid.distances), max(grid.distances))
    return SampledPath(sampler=grid.sampler, views=int(grid.views), seed=int(seed),
                       elevation_range=_check_range(grid.elevation_range, "elevation_range", -90.0, 90.0),
                       roll_range=_check_range(grid.roll_range, "roll_range", -180.0, 180.0),
                       distance_range=_check_range(distance_range, "distance_range", positive=True),
                       look_at=np.asarray(grid.look_at, dtype=np.float64))


def camera_path(grid: CameraGrid, seed: int = 0) -> CameraPath | SampledPath:
    """The spec's views: the serpentine walk of ``grid`` (sampler ``"grid"``), or its random
    views drawn with ``seed`` (validated; holds no per-point arrays, so any path is instant)."""
    if grid.sampler not in SAMPLERS:
        raise SpecError(f"camera.sampler: expected one of {', '.join(SAMPLERS)}, got {grid.sampler!r}")
    if grid.sampler != "grid":
        return sampled_path(grid, seed)
    defaults = CameraGrid()
    for key in SAMPLER_KEYS[1:]:
        if getattr(grid, key) != getattr(defaults, key):
            raise SpecError(f"camera.{key}: only for sampler = \"sphere\" or \"so3\" (this spec walks the grid); "
                            "set camera.sampler or remove the key")
    for key in ("azimuth", "roll"):
        _check_full_turn(getattr(grid, key), f"camera.{key}")
    n_el = grid.elevation.count("camera.elevation")
    # The values increase, so the largest |elevation| is at an end.
    lo, hi = grid.elevation.value_at(0), grid.elevation.value_at(n_el - 1)
    if max(abs(lo), abs(hi)) > 90 + _EPS:
        raise SpecError(f"camera.elevation: values must lie in [-90, 90] degrees, got {lo}..{hi}")
    _check_distances(grid)
    if grid.distance_mode not in ("cycle", "grid"):
        raise SpecError(f"camera.distance_mode: expected 'cycle' or 'grid', got {grid.distance_mode!r}")
    return CameraPath(azimuths=grid.azimuth, elevations=grid.elevation, rolls=grid.roll,
                      distances=tuple(float(d) for d in grid.distances), distance_mode=grid.distance_mode,
                      look_at=np.asarray(grid.look_at, dtype=np.float64))
