"""The walks: a camera path's points computed per frame index, never materialised.

:class:`CameraPath` walks a grid serpentine (a reflected mixed-radix Gray code:
consecutive frames differ by exactly one step on exactly one angle axis);
:class:`SampledPath` draws view ``i`` from its own counter-based stream (seed, i).
What a spec says and how it is checked: paths.py (:func:`paths.camera_path` builds these).
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass

import numpy as np

from spm_data.errors import SpecError
from spm_data.core.poses import camera_poses


MAX_VALUES = 10**9  # values per angle axis: frame indices stay exact in int64 and float64


@dataclass(frozen=True)
class AngleRange:
    """Inclusive ``start..stop`` in ``step`` degrees (``stop == start`` is one value)."""

    start: float
    stop: float
    step: float

    def count(self, name: str = "range") -> int:
        """How many values (a Python int, no array); raises SpecError for an empty
        or non-dividing range."""
        if not self.step > 0:
            raise SpecError(f"{name}: step must be > 0 degrees, got {self.step}")
        span = self.stop - self.start
        if span < 0:
            raise SpecError(f"{name}: empty grid, start {self.start} is above stop {self.stop}")
        count = span / self.step
        if count >= MAX_VALUES:
            raise SpecError(f"{name}: step {self.step} gives over {MAX_VALUES:,} values over "
                            f"{self.start}..{self.stop}; use a step of at least {span / (MAX_VALUES - 1):.3g} degrees")
        if abs(count - round(count)) > 1e-6:
            raise SpecError(f"{name}: step {self.step} does not divide the range "
                            f"{self.start}..{self.stop} (span {span}); pick a step that divides it")
        return int(round(count)) + 1

    def value_at(self, k) -> np.ndarray:
        """Value(s) number ``k`` (int array), float64 degrees: exactly ``values()[k]``."""
        return self.start + self.step * np.asarray(k, dtype=np.int64).astype(np.float64)

    def values(self, name: str = "range") -> np.ndarray:
        """(K,) float64 degrees; raises SpecError for an empty or non-dividing range."""
        return self.start + self.step * np.arange(self.count(name), dtype=np.float64)


@dataclass(frozen=True)
class PathPoints:
    """Some points of a path: every array has the shape of the index asked for,
    float64 (degrees / metres)."""

    azimuth: np.ndarray
    elevation: np.ndarray
    roll: np.ndarray
    distance: np.ndarray
    look_at: np.ndarray  # (3,) metres, object frame

    def poses(self):
        """Object->camera ``R`` (n, 3, 3), ``t`` (n, 3) (OpenCV camera)."""
        return camera_poses(self.azimuth, self.elevation, self.roll, self.distance, self.look_at)


class _Path(abc.ABC):
    """What every path offers: ``len``, ``indices``, ``at`` (by subclasses: grid or sampled),
    ``poses``; a subclass has ``size`` and ``look_at``."""

    @property
    @abc.abstractmethod
    def size(self) -> int:
        """Number of points (a Python int)."""

    def __len__(self) -> int:
        return self.size

    def indices(self, index=slice(None)) -> np.ndarray:
        """``index`` (a slice, an int or int array, negatives from the end, or a
        boolean mask) as int64 positions, checked against the path's length."""
        n = self.size
        if isinstance(index, slice):
            return np.arange(*index.indices(n), dtype=np.int64)
        idx = np.asarray(index)
        if idx.dtype == bool:
            if idx.shape != (n,):
                raise IndexError(f"boolean index of shape {idx.shape} does not match a path of {n} points")
            return np.flatnonzero(idx).astype(np.int64)
        if idx.size and not np.issubdtype(idx.dtype, np.integer):
            raise IndexError(f"path indices must be integers, got {idx.dtype}")
        idx = idx.astype(np.int64)
        if idx.size and (idx.min() < -n or idx.max() >= n):
            bad = idx.min() if idx.min() < -n else idx.max()
            raise IndexError(f"index {bad} is out of bounds for a path of {n} points")
        return np.where(idx < 0, idx + n, idx)

    @abc.abstractmethod
    def at(self, index=slice(None)) -> PathPoints:
        """The points at ``index`` (see :meth:`indices`)."""

    def poses(self, index=slice(None)):
        """Object->camera ``R`` (n, 3, 3), ``t`` (n, 3) for ``index`` (OpenCV camera)."""
        return self.at(index).poses()

    @property
    def azimuth(self) -> np.ndarray:
        return self.at().azimuth

    @property
    def elevation(self) -> np.ndarray:
        return self.at().elevation

    @property
    def roll(self) -> np.ndarray:
        return self.at().roll

    @property
    def distance(self) -> np.ndarray:
        return self.at().distance


@dataclass(frozen=True)
class CameraPath(_Path):
    """An ordered path, computed on demand: nothing of size ``len(path)`` is held.

    ``at(index)`` gives the points at an index array (or slice) by computing each
    index's serpentine digits (:func:`snake_digits`); ``poses(index)`` their
    poses. ``azimuth``, ``elevation``, ``roll`` and ``distance`` materialise the
    whole path as (N,) arrays: for small paths only (tests, plots).
    """

    azimuths: AngleRange
    elevations: AngleRange
    rolls: AngleRange
    distances: tuple[float, ...]
    distance_mode: str
    look_at: np.ndarray  # (3,) metres, object frame

    @property
    def sizes(self) -> tuple[int, ...]:
        """Axis sizes of the walk, outermost first: (roll, elevation, azimuth),
        with distance first in ``"grid"`` mode."""
        angles = (self.rolls.count(), self.elevations.count(), self.azimuths.count())
        return ((len(self.distances),) + angles) if self.distance_mode == "grid" else angles

    @property
    def size(self) -> int:
        """Number of points (a Python int, however large; ``len`` needs it to fit an index)."""
        return math.prod(self.sizes)

    def at(self, index=slice(None)) -> PathPoints:
        """The points at ``index`` (see :meth:`indices`)."""
        idx = self.indices(index)
        digits = snake_digits(idx, self.sizes)
        if self.distance_mode == "grid":
            dist = np.asarray(self.distances, dtype=np.float64)[digits[0]]
            digits = digits[1:]
        else:
            dist = np.asarray(self.distances, dtype=np.float64)[idx % len(self.distances)]
        return PathPoints(azimuth=self.azimuths.value_at(digits[2]), elevation=self.elevations.value_at(digits[1]),
                          roll=self.rolls.value_at(digits[0]), distance=dist, look_at=self.look_at)


@dataclass(frozen=True)
class SampledPath(_Path):
    """``views`` random views (sampler ``"sphere"`` or ``"so3"``), view ``i`` computed from
    (seed, i) alone. Angles in degrees, distances in metres (see the module docstring)."""

    sampler: str
    views: int
    seed: int
    elevation_range: tuple[float, float]
    roll_range: tuple[float, float]
    distance_range: tuple[float, float]
    look_at: np.ndarray  # (3,) metres, object frame

    @property
    def size(self) -> int:
        return self.views

    def at(self, index=slice(None)) -> PathPoints:
        """The views at ``index`` (see :meth:`indices`)."""
        idx = self.indices(index)
        u = view_uniforms(self.seed, idx, 4)
        if self.sampler == "so3":  # a uniform rotation: direction uniform on the sphere, roll on the circle
            sin_el = 2.0 * u[:, 1] - 1.0
            roll = 360.0 * u[:, 2] - 180.0
        else:  # uniform on the sphere's zone between two elevations: uniform in sin(elevation)
            lo, hi = np.sin(np.radians(self.elevation_range))
            sin_el = lo + (hi - lo) * u[:, 1]
            roll = self.roll_range[0] + (self.roll_range[1] - self.roll_range[0]) * u[:, 2]
        d_lo, d_hi = self.distance_range
        return PathPoints(azimuth=360.0 * u[:, 0], elevation=np.degrees(np.arcsin(np.clip(sin_el, -1.0, 1.0))),
                          roll=roll, distance=d_lo + (d_hi - d_lo) * u[:, 3], look_at=self.look_at)


_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


def _splitmix64(x: np.ndarray) -> np.ndarray:
    """SplitMix64's output function, elementwise on uint64 (wrapping arithmetic)."""
    with np.errstate(over="ignore"):
        z = x + _GOLDEN
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return z ^ (z >> np.uint64(31))


def view_uniforms(seed: int, index, k: int) -> np.ndarray:
    """(n, k) float64 in [0, 1): ``k`` numbers for each view of ``index`` (n,), a pure
    function of (seed, view, j): the same numbers whichever views are asked for together."""
    idx = np.asarray(index, dtype=np.int64).reshape(-1).astype(np.uint64)
    with np.errstate(over="ignore"):
        key = _splitmix64(np.asarray([seed], dtype=np.uint64))[0]
        counters = idx[:, None] * np.uint64(k) + np.arange(k, dtype=np.uint64)[None, :]
        bits = _splitmix64(counters ^ key)
    return (bits >> np.uint64(11)).astype(np.float64) * 2.0 ** -53


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


def snake_digits(index, sizes) -> list[np.ndarray]:
    """Row ``index`` of ``snake_order(sizes)`` without building it: one int64
    array per axis (outermost first), each of ``index``'s shape.

    The walk is a reflected mixed-radix Gray code: the outer digit is
    ``index // inner``, and in an odd block the inner walk runs backwards, so
    the position within the block is mirrored before the next digit is read.
    """
    rest = np.asarray(index, dtype=np.int64)
    digits = []
    for j in range(len(sizes)):
        inner = math.prod(sizes[j + 1:])
        digit, rest = np.divmod(rest, inner)
        rest = np.where(digit % 2 == 1, inner - 1 - rest, rest)
        digits.append(digit)
    return digits
