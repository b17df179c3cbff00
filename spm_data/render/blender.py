"""Blender (bpy, headless) renderer: Cycles on the CPU, or Workbench.

See spm_data.render.base for the interface and the arrays ``render`` returns. The
scene (camera with the spec's intrinsics, lights that move with the camera,
world, render settings) is built once per renderer and the mesh once per
instance; a frame moves the camera (and sets the frame's draws and distractors)
and renders one multi-layer EXR (Combined, Depth, Object Index, Normal when asked)
that blender_exr.py reads back with the OpenEXR package. Cycles keeps its synced scene between
frames (persistent data) and, with a transparent film, renders only a border
around the objects (blender_scene.border_box); Blender 5.0.1 headless offers no
way to read a render without a file.

Blender runs in worker processes only (spm_data.pipelines.render_jobs): a crash or a
leak in Blender takes down a worker, never the run.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import warnings

import numpy as np

from spm_data.errors import RenderError
from spm_data.core.poses import K_to_corner_origin, cv_to_gl_camera_to_world
from spm_data.core.raster import CLIP_FAR, CLIP_NEAR
from spm_data.render.base import Renderer, assigned_gpu, light_rotations, rotate_normals
from spm_data.render.blender_exr import INSTALL_HINT, import_openexr, read_frame
from spm_data.render.blender_scene import border_box, captured_output, cycles_device, mesh_data, remove_mesh_data, tail


def _import_bpy():
    try:
        import bpy
        import mathutils
    except ImportError as exc:
        raise RenderError(f"Blender's bpy module is not installed ({exc}); {INSTALL_HINT}") from None
    return bpy, mathutils


class BlenderRenderer(Renderer):
    """bpy renderer for one spec (engine, samples, image size, intrinsics, lights)."""

    name = "blender"

    def __init__(self, spec):
        super().__init__(spec)
        self._bpy, self._mathutils = _import_bpy()
        self._exr = import_openexr()
        settings = spec.render.blender
        self.engine = settings.engine
        if self.engine == "eevee":
            warnings.warn("EEVEE needs a GPU (about 40 s a frame on this CPU); rendering with Cycles instead",
                          stacklevel=2)
            self.engine = "cycles"
        self._tmp = tempfile.mkdtemp(prefix="spm-blender-")
        self._exr_path = os.path.join(self._tmp, "frame.exr")
        self._log = os.path.join(self._tmp, "blender.log")
        self._object = None
        self._points = np.zeros((0, 3))  # the target's distinct vertices, for its render border
        self._frame_K = self.K           # the frame's intrinsics (randomised per frame or the spec's)
        self._crop = None  # (x0, y0, x1, y1): the pixels the frame's render border keeps, or None
        self._slots, self._distractor_data = [], {}  # distractor objects, and their meshes by id(mesh)
        try:
            with captured_output(self._log):
                self._build_scene()
        except RenderError:
            raise
        except Exception as exc:  # bpy raises RuntimeError/TypeError for scene setup problems
            raise RenderError(f"Blender could not set up the scene ({exc}) {tail(self._log)}".strip()) from None

    # ------------------------------------------------------------------ scene
    def _build_scene(self) -> None:
        self._bpy.ops.wm.read_factory_settings(use_empty=True)
        sc = self._bpy.context.scene
        self._set_engine(sc)
        self.device = self._set_device(sc)
        self._set_output(sc)
        self._add_camera(sc)
        self._add_lights(sc)

    def _set_engine(self, sc) -> None:
        s = self.spec.render.blender
        r = sc.render
        r.resolution_x, r.resolution_y, r.resolution_percentage = self.width, self.height, 100
        r.film_transparent = s.film_transparent
        if s.threads > 0:  # else Blender's default, all cores (measured fastest, even with 2 workers)
            r.threads_mode, r.threads = "FIXED", s.threads
        # Keep the synced scene (Cycles: objects, BVH, shaders, images) between frames; a frame
        # then re-syncs only what changed (camera, lights, materials, distractors). Cycles then
        # ignores changes to scene.cycles settings made after the first frame: set them all here.
        r.use_persistent_data = True
        if self.engine == "cycles":
            r.engine = "CYCLES"
            sc.cycles.device = "CPU"
            sc.cycles.samples = s.samples
            sc.cycles.use_denoising = s.denoise
            sc.cycles.use_adaptive_sampling = False
            # Depth and object index are sampled at the pixel centres K describes;
            # a wider pixel filter would smear them across the silhouette edge.
            sc.cycles.filter_width = 0.01
            sc.cycles.max_bounces = 4
        else:
            r.engine = "BLENDER_WORKBENCH"
            sc.display.shading.light = "STUDIO"
            sc.display.shading.color_type = "TEXTURE"
            sc.display.render_aa = "OFF"  # pixel-centre samples, as for Cycles
        sc.view_settings.view_transform = "Standard"

    def _set_device(self, sc) -> str:
        """Where Cycles renders (cycles_device): "CPU" or the GPU backend used; with --gpus, this
        worker's GPU only."""
        if self.engine != "cycles":
            sc.cycles.device = "CPU"
            return "CPU"
        return cycles_device(self._bpy, sc, self.spec.render.blender.device, assigned_gpu())

    def _set_output(self, sc) -> None:
        """One multi-layer EXR a frame: Combined, Depth and Object Index, 32-bit, uncompressed."""
        layer = sc.view_layers[0]
        layer.use_pass_z = True
        layer.use_pass_object_index = True
        layer.use_pass_normal = self.outputs.normals
        r = sc.render
        img = r.image_settings
        img.media_type = "MULTI_LAYER_IMAGE"
        img.file_format = "OPEN_EXR_MULTILAYER"
        img.color_depth = "32"
        img.exr_codec = "NONE"
        r.filepath = self._exr_path
        r.use_file_extension = False
        r.use_crop_to_border = True  # with a render border (_set_border) the EXR holds only the border

    def _add_camera(self, sc) -> None:
        cam = self._bpy.data.cameras.new("spm-camera")
        cam.sensor_fit = "HORIZONTAL"
        cam.sensor_width = 36.0
        self._set_intrinsics(cam, self.K)
        cam.clip_start, cam.clip_end = CLIP_NEAR, CLIP_FAR
        self._camera = self._bpy.data.objects.new("spm-camera", cam)
        sc.collection.objects.link(self._camera)
        sc.camera = self._camera

    def _set_intrinsics(self, cam, K) -> None:
        """Blender's lens and shift for the OpenCV ``K`` (3, 3); square pixels (fx is used)."""
        W, H = self.width, self.height
        cam.lens = K[0, 0] * cam.sensor_width / W
        # Blender's principal point sits at the image centre plus shift (in units of the larger side).
        cx, cy = K_to_corner_origin(K)[:2, 2]
        cam.shift_x = (W / 2.0 - cx) / max(W, H)
        cam.shift_y = (cy - H / 2.0) / max(W, H)

    def _add_lights(self, sc) -> None:
        """Suns parented to the camera (as the pyrender backend's lights move with it), and
        the ambient term as the world's colour."""
        bpy, lighting = self._bpy, self.spec.lighting
        rotations = light_rotations(lighting.lights)
        self._suns = []
        for i in range(self.max_lights):
            sun = bpy.data.lights.new(f"spm-sun-{i}", "SUN")
            sun.energy = lighting.strength
            obj = bpy.data.objects.new(f"spm-sun-{i}", sun)
            sc.collection.objects.link(obj)
            obj.parent = self._camera
            self._set_rotation(obj, rotations[i] if i < len(rotations) else np.eye(3))
            self._suns.append(obj)
        world = bpy.data.worlds.new("spm-world")
        sc.world = world
        if world.node_tree is None:  # Blender < 5 needs asking; 5.x always has nodes
            world.use_nodes = True
        self._background = world.node_tree.nodes.get("Background")
        a = lighting.ambient
        self._background.inputs["Color"].default_value = (a, a, a, 1.0)
        self._background.inputs["Strength"].default_value = 1.0

    def _set_rotation(self, obj, rotation) -> None:
        local = np.eye(4)
        local[:3, :3] = rotation
        obj.matrix_basis = self._mathutils.Matrix(local.tolist())

    def _apply_draws(self, draws) -> None:
        """Set the frame's intrinsics, lights, ambient light and material (FrameDraws)."""
        self._set_intrinsics(self._camera.data, draws.K)
        for i, sun in enumerate(self._suns):
            lit = i < len(draws.light_strengths)
            if lit:
                self._set_rotation(sun, draws.light_rotations[i])
            sun.data.energy = float(draws.light_strengths[i]) if lit else 0.0
            sun.data.color = tuple(draws.light_colors[i]) if lit else (1.0, 1.0, 1.0)
        a = draws.ambient
        self._background.inputs["Color"].default_value = (a, a, a, 1.0)
        bsdf = self._object.active_material.node_tree.nodes["Principled BSDF"]
        bsdf.inputs["Roughness"].default_value = draws.roughness
        bsdf.inputs["Metallic"].default_value = draws.metallic
        factor = self._object.active_material.node_tree.nodes.get("spm-base-color")
        if factor is not None:
            factor.inputs["B"].default_value = (*draws.base_color, 1.0)

    def version(self) -> str:
        return f"Blender {self._bpy.app.version_string}"

    def settings(self) -> dict:
        s = self.spec.render.blender
        out = {"engine": self.engine, "film_transparent": s.film_transparent, "threads": s.threads,
               **self.lighting_settings()}
        if self.engine == "cycles":
            out.update(samples=s.samples, denoise=s.denoise, filter_width=0.01, device=self.device)
        return out

    # ------------------------------------------------------------------ mesh
    def set_mesh(self, mesh) -> None:
        """Replace the target with ``mesh`` (a TexturedMesh): mesh data, UVs, normals, texture."""
        bpy = self._bpy
        # Persistent data (_set_engine): Cycles keeps images by their datablock's address, and
        # a new texture may be given the freed one's, so it would keep the old pixels (seen).
        # Switching the setting off frees the kept scene; the next frame builds it anew.
        render = bpy.context.scene.render
        render.use_persistent_data = False
        render.use_persistent_data = True
        if self._object is not None:
            old = self._object.data
            bpy.data.objects.remove(self._object)
            remove_mesh_data(bpy, old)
        obj = bpy.data.objects.new(mesh.name, mesh_data(bpy, mesh, base_color=bool(self.spec.randomize.base_color)))
        obj.pass_index = 1
        bpy.context.scene.collection.objects.link(obj)
        self._object = obj
        self._points = np.unique(np.asarray(mesh.vertices, dtype=np.float64), axis=0)

    def _place_distractors(self, R, t, distractors) -> None:
        """Show one object per PlacedDistractor (slot k: pass index 2 + k), posed in
        the target's (the world's) frame; hide the slots not used."""
        bpy = self._bpy
        world_from_camera = np.eye(4)
        world_from_camera[:3, :3], world_from_camera[:3, 3] = R.T, -R.T @ t
        for k, d in enumerate(distractors):
            if id(d.mesh) not in self._distractor_data:  # the mesh is kept, so its id stays its own
                self._distractor_data[id(d.mesh)] = (d.mesh, mesh_data(bpy, d.mesh))
            data = self._distractor_data[id(d.mesh)][1]
            if k == len(self._slots):
                slot = bpy.data.objects.new(f"spm-distractor-{k}", data)
                slot.pass_index = 2 + k
                bpy.context.scene.collection.objects.link(slot)
                self._slots.append(slot)
            slot = self._slots[k]
            slot.data = data
            slot.matrix_world = self._mathutils.Matrix((world_from_camera @ d.matrix()).tolist())
            slot.hide_render = False
        for slot in self._slots[len(distractors):]:
            slot.hide_render = True

    # ------------------------------------------------------------------ frames
    def render(self, R, t, draws=None, distractors=()) -> dict:
        if self._object is None:
            raise RenderError("set_mesh must be called before render")
        if draws is not None:
            self._apply_draws(draws)
        if distractors or self._slots:
            self._place_distractors(R, t, distractors)
        self._camera.matrix_world = self._mathutils.Matrix(cv_to_gl_camera_to_world(R, t).tolist())
        self._frame_K = draws.K if draws is not None else self.K
        s = self.spec.render.blender
        if self.engine == "cycles" and s.film_transparent and not s.denoise:  # a denoiser would see only the crop
            self._set_border(np.asarray(R, dtype=np.float64), np.asarray(t, dtype=np.float64), distractors)
        try:
            with captured_output(self._log):
                self._bpy.ops.render.render(write_still=True)
        except RuntimeError as exc:
            raise RenderError(f"Blender failed to render a frame ({exc}) {tail(self._log)}".strip()) from None
        out = self._read_exr()
        if distractors or self.outputs.instances or self.outputs.normals:
            out["instances"] = self._instances
        if self.outputs.normals:
            # Blender's normals are in the world
            world_to_camera = np.stack([np.eye(3), *([R] * (1 + len(distractors)))])
            out["normals"] = rotate_normals(self._normals, self._instances, world_to_camera)
        return out

    def _set_border(self, R, t, distractors=()) -> None:
        """Let Cycles trace only the pixels around what it can see: a render border, cropped,
        around the projection of the target's and the distractors' vertices (from the meshes
        given, not Blender's bounding boxes, which lag a mesh swap by a frame), plus the
        margin. With a transparent film the pixels outside are background, which _read_exr
        fills in as a full frame has it (tests/render/test_blender.py); else the full frame."""
        r = self._bpy.context.scene.render
        points = [self._points @ R.T + t] + [(np.asarray(d.mesh.vertices) * d.size) @ d.R.T + d.t
                                             for d in distractors]
        self._crop = border_box(np.concatenate(points), self._frame_K, self.width, self.height)
        r.use_border = self._crop is not None
        if self._crop is not None:
            x0, y0, x1, y1 = self._crop
            W, H = self.width, self.height
            # Blender takes pixel int(fraction * size) (render_pipeline.cc, disprect): a half pixel
            # more makes that exact; its y counts from the bottom.
            r.border_min_x, r.border_max_x = (x0 + 0.5) / W, min(1.0, (x1 + 0.5) / W)
            r.border_min_y, r.border_max_y = (H - y1 + 0.5) / H, min(1.0, (H - y0 + 0.5) / H)

    def _read_exr(self) -> dict:
        out = read_frame(self._exr, self._exr_path, normals=self.outputs.normals, distractor_slots=bool(self._slots),
                         crop=self._crop, height=self.height, width=self.width)
        self._instances, self._normals = out.pop("ids"), out.pop("world_normals", None)
        return out

    def close(self) -> None:
        shutil.rmtree(self._tmp, ignore_errors=True)
