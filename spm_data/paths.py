"""Camera paths: an ordered walk over an azimuth x elevation (x roll) x distance grid.

The walk is serpentine (a reflected mixed-radix Gray code): consecutive frames
differ by exactly one step on exactly one angle axis, so a path is a camera
moving in 5 degree steps, as in the paper. The pose convention is in poses.py.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spm_data.errors import SpecError
from spm_data.poses import camera_poses

_EPS = 1e-9


@dataclass(frozen=True)
class AngleRange:
    """Inclusive ``start..stop`` in ``step`` degrees (``stop == start`` is one value)."""

    start: float
    stop: float
    step: float

    def values(self, name: str = "range") -> np.ndarray:
        """(K,) float64 degrees; raises SpecError for an empty or non-dividing range."""
        if not self.step > 0:
            raise SpecError(f"{name}: step must be > 0 degrees, got {self.step}")
        span = self.stop - self.start
        if span < 0:
            raise SpecError(f"{name}: empty grid, start {self.start} is above stop {self.stop}")
        count = span / self.step
        if abs(count - round(count)) > 1e-6:
            raise SpecError(f"{name}: step {self.step} does not divide the range "
                            f"{self.start}..{self.stop} (span {span}); pick a step that divides it")
        return self.start + self.step * np.arange(int(round(count)) + 1, dtype=np.float64)


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


@dataclass(frozen=True)
class CameraPath:
    """An ordered path: every array is (N,) float64 (degrees / metres)."""

    azimuth: np.ndarray
    elevation: np.ndarray
    roll: np.ndarray
    distance: np.ndarray
    look_at: np.ndarray  # (3,) metres, object frame

    def __len__(self) -> int:
        return int(self.azimuth.shape[0])

    def poses(self, index=slice(None)):
        """Object->camera ``R`` (n, 3, 3), ``t`` (n, 3) for ``index`` (OpenCV camera)."""
        return camera_poses(self.azimuth[index], self.elevation[index], self.roll[index],
                            self.distance[index], self.look_at)


def snake_order(sizes: list[int]) -> np.ndarray:
    """(prod(sizes), len(sizes)) int indices, first axis outermost, walked so
    that consecutive rows differ by one in exactly one column."""
    if not sizes:
        return np.zeros((1, 0), dtype=np.int64)
    inner = snake_order(sizes[1:])
    blocks = []
    for i in range(sizes[0]):
        block = inner if i % 2 == 0 else inner[::-1]
        blocks.append(np.column_stack([np.full(len(block), i, dtype=np.int64), block]))
    return np.concatenate(blocks, axis=0)


def camera_path(grid: CameraGrid) -> CameraPath:
    """Walk ``grid`` into an ordered :class:`CameraPath` (validated)."""
    az = grid.azimuth.values("camera.azimuth")
    el = grid.elevation.values("camera.elevation")
    rl = grid.roll.values("camera.roll")
    if np.any(np.abs(el) > 90 + _EPS):
        raise SpecError(f"camera.elevation: values must lie in [-90, 90] degrees, got {el.min()}..{el.max()}")
    distances = np.asarray(grid.distances, dtype=np.float64)
    if distances.size == 0:
        raise SpecError("camera.distances: empty list; give at least one distance in metres")
    if np.any(~np.isfinite(distances)) or np.any(distances <= 0):
        raise SpecError(f"camera.distances: every distance must be a finite number > 0 metres, got {list(grid.distances)}")
    if grid.distance_mode not in ("cycle", "grid"):
        raise SpecError(f"camera.distance_mode: expected 'cycle' or 'grid', got {grid.distance_mode!r}")
    if grid.distance_mode == "grid":
        idx = snake_order([len(distances), len(rl), len(el), len(az)])
        dist = distances[idx[:, 0]]
        idx = idx[:, 1:]
    else:
        idx = snake_order([len(rl), len(el), len(az)])
        dist = distances[np.arange(len(idx)) % len(distances)]
    return CameraPath(azimuth=az[idx[:, 2]], elevation=el[idx[:, 1]], roll=rl[idx[:, 0]],
                      distance=dist, look_at=np.asarray(grid.look_at, dtype=np.float64))
