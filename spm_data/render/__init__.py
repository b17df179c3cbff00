"""Renderers behind one small interface; each backend is one module, imported lazily.

A renderer is built once per worker with ``make_renderer(spec)``; then, for
each mesh instance, ``set_mesh(mesh)`` builds the scene once, and
``render(R, t)`` only moves the camera. ``render`` returns a dict:

* ``rgb``   (H, W, 3) uint8, sRGB, premultiplied over black (background is
  composited later by ``spm_data.backgrounds``)
* ``alpha`` (H, W) float32 in [0, 1], object coverage per pixel
* ``depth`` (H, W) float32, metres along the camera's z axis (OpenCV frame),
  0.0 where no surface was hit
* ``mask``  (H, W) uint8, 1 where the object is, else 0

``R`` (3, 3) and ``t`` (3,) are object->camera in the OpenCV convention of
spm_data.poses; intrinsics come from the spec (``spec_intrinsics``).
"""

from __future__ import annotations

import importlib

import numpy as np

from spm_data.errors import RenderError
from spm_data.poses import intrinsics_from_fov

BACKENDS = {"pyrender": "spm_data.render.pyrender_backend", "blender": "spm_data.render.blender"}
OUTPUTS = ("rgb", "alpha", "depth", "mask")


def spec_intrinsics(spec) -> np.ndarray:
    """(3, 3) float64 K of a RenderSpec (OpenCV pixel centres)."""
    return intrinsics_from_fov(spec.image.fov, spec.image.width, spec.image.height)


def make_renderer(spec, name: str | None = None):
    """Build the renderer ``name`` (default: the spec's) for ``spec``."""
    name = name or spec.render.renderer
    if name not in BACKENDS:
        raise RenderError(f"unknown renderer {name!r}; expected one of {', '.join(BACKENDS)}")
    module = importlib.import_module(BACKENDS[name])
    return module.Renderer(spec)


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
