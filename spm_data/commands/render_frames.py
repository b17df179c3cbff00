"""One rendered frame, as a shard stores it: the spec's draws and distractors, the
render, the background, and the opt-in outputs (spm_data.commands.render_jobs
streams these into shards).
"""

from __future__ import annotations

import zlib

import numpy as np

from spm_data.core.backgrounds import background_image, composite
from spm_data.core.distractors import place_distractors
from spm_data.core.randomize import frame_draws, lights_width
from spm_data.core.raster import object_coords
from spm_data.io.shards import FIELDS, OPTIONAL_FIELDS


def frame_rng(spec, instance: int, path_index: int) -> np.random.Generator:
    """Per-frame randomness (backgrounds): independent of shard layout and worker."""
    return np.random.default_rng([spec.seed, zlib.crc32(spec.class_name.encode()), instance, path_index, 1])


class FrameMaker:
    """Renders frames of one spec with ``renderer``: ``image_fields`` per frame,
    and the per-frame labels ``make`` returns besides the camera path's."""

    def __init__(self, spec, renderer):
        self.spec, self.renderer = spec, renderer
        self.distractors = spec.distractors.count > 0
        self.randomized = spec.randomize.enabled
        outputs = spec.outputs
        self.image_fields = ("rgb", "depth", "mask") + (("visible_mask",) if self.distractors else ()) + tuple(
            f for f in ("instances", "normals", "coords") if getattr(outputs, f))

    def bytes_per_pixel(self) -> int:
        """Raw bytes a frame's image fields take per pixel."""
        table = {**FIELDS, **OPTIONAL_FIELDS}
        return sum(np.dtype(table[f][0]).itemsize * (3 if table[f][1][-1] == 3 else 1) for f in self.image_fields)

    def scene(self, mesh, instance: int, path_index: int, R, t) -> tuple:
        """(draws, placement) of frame (``instance``, ``path_index``): its FrameDraws (None
        without ``[randomize]``) and its PlacedDistractors (None without ``[distractors]``);
        the renderer draws it as ``render(R, t, draws, placement.distractors)``."""
        draws = frame_draws(self.spec, instance, path_index, self.renderer.K) if self.randomized else None
        K = draws.K if draws is not None else self.renderer.K
        placement = place_distractors(self.spec, mesh, R, t, K, instance, path_index) if self.distractors else None
        return draws, placement

    def make(self, mesh, instance: int, path_index: int, R, t) -> tuple[dict, dict]:
        """(images {field: one frame's array}, labels {field: one frame's value}) of frame
        (``instance``, ``path_index``), the target ``mesh`` posed by ``R``, ``t``."""
        spec = self.spec
        draws, placement = self.scene(mesh, instance, path_index, R, t)
        K = draws.K if draws is not None else self.renderer.K
        out = self.renderer.render(R, t, draws=draws, distractors=placement.distractors if placement else ())
        kind = draws.background if draws is not None else spec.background.kind
        rgb = out["rgb"]
        if kind != "black":
            rgb = composite(rgb, out["alpha"], background_image(spec, frame_rng(spec, instance, path_index), kind))
        images = {"rgb": rgb, "depth": out["depth"], "mask": out["mask"]}
        labels = {"K": K}
        if draws is not None:
            labels.update(draws.labels(lights_width(spec)))
        if placement is not None:
            images["mask"] = placement.amodal.astype(np.uint8)
            images["visible_mask"] = out["mask"] & images["mask"]
            labels.update(self._distractor_labels(placement, images))
        for field in ("instances", "normals"):
            if field in self.image_fields:
                images[field] = out[field]
        if "coords" in self.image_fields:
            images["coords"] = object_coords(out["depth"], out["mask"] > 0, K, R, t).astype(np.float16)
        return images, labels

    def _distractor_labels(self, placement, images) -> dict:
        n = self.spec.distractors.count
        mesh = np.full(n, -1, np.int64)
        Rs, ts, sizes = np.zeros((n, 3, 3)), np.zeros((n, 3)), np.zeros(n)
        for k, d in enumerate(placement.distractors):
            mesh[k], Rs[k], ts[k], sizes[k] = d.mesh_index, d.R, d.t, d.size
        area = int(images["mask"].sum())
        seen = int(images["visible_mask"].sum())
        return {"visible_target": np.float32(placement.visible_target), "distractor_mesh": mesh,
                "distractor_R": Rs, "distractor_t": ts, "distractor_size": sizes,
                "occlusion_fraction": np.float32(1.0 - seen / area if area else 0.0)}
