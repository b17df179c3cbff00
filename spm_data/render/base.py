"""The abstract :class:`Renderer` every backend implements, and what the backends share
(intrinsics from the spec, lights around the camera, normals and masks). Nothing here loads
bpy or OpenGL; the backends are registered in spm_data/render/__init__.py."""

from __future__ import annotations

import abc
import importlib
import os
import re

import numpy as np

from spm_data.errors import RenderError
from spm_data.core.poses import intrinsics_from_fov
from spm_data.core.randomize import fixed_light_rotations, max_lights

OUTPUTS = ("rgb", "alpha", "depth", "mask")
GPU_VARIABLE = "SPM_RENDER_GPU"  # the GPU a worker renders on, an index into its backend's GPU list (executors set it)
# GL contexts (render processes) per GPU when --workers asks for more. From issue 37's measurements on
# one H100 (bare pyrender loops at 256x256, all processes together): 804 fps in 1 process, 2,193 in 4,
# 2,423 in 8: four contexts give 90% of eight's frames with half the contexts, and leave the other
# workers' cores to each process's pipeline threads (compositing, compression). Not measured by us
# on a GPU (docs/scaling.md).
CONTEXTS_PER_GPU = 4


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
    readback_seconds: float = 0.0  # cumulative seconds of render spent reading the frame back (backends that can tell)

    def __init__(self, spec):
        self.spec = spec
        self.width, self.height = spec.image.width, spec.image.height
        self.K = spec_intrinsics(spec)
        self.outputs = spec.outputs
        self.max_lights = max_lights(spec)

    def lighting_settings(self) -> dict:
        """The spec's lighting as every frame has it: ``ambient``, ``lights`` (count) and
        ``strength``, each the fixed value, or its ``[low, high]`` range where ``[randomize]``
        draws it per frame; with ``[randomize]``, ``randomized``: the keys drawn per frame."""
        li, rz = self.spec.lighting, self.spec.randomize
        out = {"ambient": li.ambient, "lights": li.lights, "strength": li.strength}
        if not rz.enabled:
            return out
        for key, drawn in (("ambient", rz.ambient), ("lights", rz.lights), ("strength", rz.light_strength)):
            if drawn:
                out[key] = [int(v) for v in drawn] if key == "lights" else list(drawn)
        default = type(rz)()
        out["randomized"] = sorted(k for k in vars(default) if getattr(rz, k) != getattr(default, k))
        return out

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
    def render(self, R, t, draws=None, distractors=()) -> dict:
        """One frame from the camera at ``R``, ``t``: the arrays listed in the class docstring."""

    def close(self) -> None:
        """Free what the backend holds (nothing by default)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def light_rotations(count: int) -> np.ndarray:
    """(count, 3, 3) rotations, in the camera's GL frame, of the spec's ``count`` lights
    that move with the camera (spm_data.core.randomize.fixed_light_rotations)."""
    return fixed_light_rotations(count)


def decode_normals(coded: np.ndarray, instances: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """Normals drawn as colours -> (H, W, 3) float32 unit normals, camera frame (OpenCV).

    coded: (H, W, 3) uint8, each object's own-frame normal n as (n + 1) / 2 * 255;
    instances (H, W) uint8 ids; rotations (I, 3, 3) float64, each id's frame ->
    camera (row 0 unused). Pixels with id 0 come out 0."""
    return rotate_normals(coded.astype(np.float32) * (2.0 / 255.0) - 1.0, instances, rotations)


def rotate_normals(normals: np.ndarray, instances: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """(H, W, 3) normals, each in the frame of its pixel's instance id (instances (H, W)
    uint8) -> (H, W, 3) float32 unit normals in the camera frame, by ``rotations``
    (I, 3, 3) (row 0 unused); pixels with id 0 come out 0."""
    n = np.einsum("hwij,hwj->hwi", rotations[instances].astype(np.float32), normals.astype(np.float32))
    length = np.linalg.norm(n, axis=-1, keepdims=True)
    n = n / np.maximum(length, 1e-12)
    return np.where((instances[..., None] > 0) & (length > 0), n, 0.0).astype(np.float32)


def mask_from_depth(depth: np.ndarray) -> np.ndarray:
    """(H, W) uint8 mask of pixels with a surface (depth > 0)."""
    return (depth > 0).astype(np.uint8)


def labels_agreeing_with_depth(labels: np.ndarray, depth: np.ndarray, label_depth: np.ndarray) -> np.ndarray:
    """(H, W) uint8 instance labels that agree with ``depth`` (H, W) float32 metres, 0 = nothing.

    ``labels`` (H, W) uint8 come from a second GL pass whose own depth is ``label_depth``. On Mesa
    that pass (and pyrender's depth-only one) now and then covers a silhouette pixel the colour pass
    did not, or the reverse: about one pixel in a hundred frames (why is not established). A label
    is kept where both passes drew the same depth; elsewhere the pixel takes the label of its
    8-neighbour (among the kept, non-zero ones) nearest in depth, and none where depth has no
    surface. So the visible mask and the depth a BOP export writes say the same of every pixel."""
    labels = np.where(depth > 0, labels, 0).astype(np.uint8)
    doubtful = (depth > 0) & ((labels == 0) | (label_depth != depth))
    if not doubtful.any():
        return labels
    kept_depth = np.where((depth > 0) & ~doubtful & (labels > 0), depth, np.inf)
    h, w = depth.shape
    pad_d = np.pad(kept_depth, 1, constant_values=np.inf)
    pad_l = np.pad(labels, 1)
    ys, xs = np.nonzero(doubtful)
    shifts = [(dy, dx) for dy in (0, 1, 2) for dx in (0, 1, 2) if (dy, dx) != (1, 1)]
    near = np.stack([pad_d[ys + dy, xs + dx] for dy, dx in shifts])          # (8, n) neighbours' depths
    names = np.stack([pad_l[ys + dy, xs + dx] for dy, dx in shifts])
    best = np.argmin(np.abs(near - depth[ys, xs]), axis=0)
    found = np.isfinite(near[best, np.arange(len(ys))])
    labels[ys[found], xs[found]] = names[best, np.arange(len(ys))][found]
    return labels


# --------------------------------------------------------------------------- GPUs

def parse_gpus(text) -> tuple[int, ...] | None:
    """``--gpus``: None when not given (every GPU listed), else ``"0,1,3"`` -> (0, 1, 3);
    RenderError (one line) for any other text or a GPU named twice."""
    if text is None:
        return None
    parts = [part.strip() for part in str(text).split(",")]
    if not all(re.fullmatch(r"[0-9]{1,4}", part) for part in parts):
        raise RenderError(f"--gpus {text!r}: expected GPU indices separated by commas, such as 0 or 0,1,3")
    gpus = tuple(int(part) for part in parts)
    twice = [g for k, g in enumerate(gpus) if g in gpus[:k]]
    if twice:
        raise RenderError(f"--gpus {text!r}: GPU {twice[0]} is named twice")
    return gpus


def choose_gpus(wanted, listed, lister: str = "this machine") -> tuple[int, ...]:
    """The GPUs a run renders on: ``wanted`` (parse_gpus) out of ``listed`` (the indices a backend
    lists, ``lister`` saying which); None wants every listed GPU (none listed: the CPU, ()).
    RenderError (one line) when GPUs are wanted and none is listed, or one wanted is not."""
    listed = tuple(listed)
    if wanted is None:
        return listed
    named = ",".join(str(g) for g in wanted)
    if not listed:
        raise RenderError(f"--gpus {named}: no GPU here ({lister} lists none); leave --gpus out to render on the CPU")
    missing = [g for g in wanted if g not in listed]
    if missing:
        raise RenderError(f"--gpus {named}: there is no GPU {missing[0]}; {lister} lists {len(listed)}: "
                          f"{', '.join(str(g) for g in listed)}")
    return tuple(wanted)


CONTEXTS_VARIABLE = "SPM_CONTEXTS_PER_GPU"  # a user's own CONTEXTS_PER_GPU (docs/scaling.md: measure it)


def contexts_per_gpu(environ=None) -> int:
    """GL contexts per GPU: $SPM_CONTEXTS_PER_GPU (1-64), else CONTEXTS_PER_GPU. RenderError
    (one line) for another value."""
    value = (os.environ if environ is None else environ).get(CONTEXTS_VARIABLE, "").strip()
    if not value:
        return CONTEXTS_PER_GPU
    if not value.isdigit() or not 1 <= int(value) <= 64:
        raise RenderError(f"{CONTEXTS_VARIABLE}={value!r}: expected a whole number of GL contexts per GPU from 1 "
                          f"to 64; unset it for the default, {CONTEXTS_PER_GPU}")
    return int(value)


def gl_processes(workers: int, gpus: int, per_gpu: int | None = None) -> int:
    """Render processes (one GL context each) carrying ``workers``-way work: one per worker on
    the CPU (``gpus`` = 0: llvmpipe draws on the process's own cores), at most ``per_gpu``
    (default: contexts_per_gpu()) per GPU otherwise (contexts on one GPU take turns; more of
    them only add switches)."""
    if gpus <= 0:
        return max(1, workers)
    return max(1, min(workers, (per_gpu or contexts_per_gpu()) * gpus))


def assigned_gpu(environ=None) -> int | None:
    """The GPU this worker renders on (GPU_VARIABLE, set by the executors), or None."""
    value = (os.environ if environ is None else environ).get(GPU_VARIABLE, "")
    return int(value) if value.isdigit() else None


def visible_gpus(renderer: str):
    """``(gpus, lister)``: the GPU indices renderer ``renderer`` lists in this process and who lists
    them (pyrender: EGL), or None for a backend that lists its GPUs only where it renders
    (Blender, in its workers: its backend module has no ``visible_gpus``)."""
    from spm_data.render import RENDERERS

    lister = getattr(importlib.import_module(RENDERERS[renderer].module), "visible_gpus", None)
    return None if lister is None else lister()
