"""Renderers behind one abstract interface (:class:`Renderer`); each backend is one
module, imported lazily by :func:`make_renderer`, so nothing here loads bpy or OpenGL.
"""

from __future__ import annotations

import abc
import importlib

import numpy as np

from spm_data.errors import RenderError
from spm_data.core.poses import intrinsics_from_fov

# name -> (module, class): imported only when asked for
BACKENDS = {"pyrender": ("spm_data.render.pyrender_backend", "PyrenderRenderer"),
            "blender": ("spm_data.render.blender", "BlenderRenderer")}
OUTPUTS = ("rgb", "alpha", "depth", "mask")


def spec_intrinsics(spec) -> np.ndarray:
    """(3, 3) float64 K of a RenderSpec (OpenCV pixel centres)."""
    return intrinsics_from_fov(spec.image.fov, spec.image.width, spec.image.height)


class Renderer(abc.ABC):
    """One spec's renderer: built once per worker, a scene per mesh, a camera move per frame.

    ``set_mesh(mesh)`` builds the scene for a ``spm_data.core.meshes.TexturedMesh``
    once; ``render(R, t)`` then only moves the camera. ``R`` (3, 3) and ``t`` (3,)
    float64 map object to camera in the OpenCV convention of spm_data.core.poses;
    the intrinsics are ``self.K`` (3, 3) float64, from the spec (spec_intrinsics).
    ``render`` returns a dict of (H = spec.image.height, W = spec.image.width):

    * ``rgb``   (H, W, 3) uint8, sRGB, premultiplied over black (the background
      is composited later, by spm_data.core.backgrounds)
    * ``alpha`` (H, W) float32 in [0, 1], the object's coverage of each pixel
    * ``depth`` (H, W) float32, metres along the camera's z axis (OpenCV frame),
      0.0 where no surface was hit; sampled at the pixel centres K describes
    * ``mask``  (H, W) uint8, 1 where the object is, else 0

    Backends raise RenderError (one line) for what they cannot do. ``close()``
    frees what the backend holds; a renderer is also a context manager.
    """

    name: str = ""

    def __init__(self, spec):
        self.spec = spec
        self.width, self.height = spec.image.width, spec.image.height
        self.K = spec_intrinsics(spec)

    @abc.abstractmethod
    def version(self) -> str:
        """The backend and its version, e.g. ``pyrender 0.1.45`` (recorded in every shard)."""

    @abc.abstractmethod
    def settings(self) -> dict:
        """JSON-able settings that change pixels (recorded in every shard)."""

    @abc.abstractmethod
    def set_mesh(self, mesh) -> None:
        """Build the scene around ``mesh`` (a TexturedMesh), replacing the previous one."""

    @abc.abstractmethod
    def render(self, R, t) -> dict:
        """One frame from the camera at ``R``, ``t``: the arrays listed in the class docstring."""

    def close(self) -> None:
        """Free what the backend holds (nothing by default)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def make_renderer(spec, name: str | None = None) -> Renderer:
    """Build the renderer ``name`` (default: the spec's) for ``spec``."""
    name = name or spec.render.renderer
    if name not in BACKENDS:
        raise RenderError(f"unknown renderer {name!r}; expected one of {', '.join(BACKENDS)}")
    module, cls = BACKENDS[name]
    return getattr(importlib.import_module(module), cls)(spec)


def light_rotations(count: int) -> list[np.ndarray]:
    """(3, 3) rotations, in the camera's GL frame, of ``count`` lights that move
    with the camera: a head light, the others on a 40-degree cone around it."""
    rots = []
    for i in range(count):
        if i == 0:
            rots.append(np.eye(3))
            continue
        phi = 2 * np.pi * (i - 1) / max(count - 1, 1)
        axis = np.array([np.cos(phi), np.sin(phi), 0.0])
        angle = np.radians(40.0)
        k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        rots.append(np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k)
    return rots


def mask_from_depth(depth: np.ndarray) -> np.ndarray:
    """(H, W) uint8 mask of pixels with a surface (depth > 0)."""
    return (depth > 0).astype(np.uint8)
