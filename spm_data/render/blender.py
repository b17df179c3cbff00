"""Blender (bpy, headless) renderer: Cycles on the CPU, or Workbench.

See spm_data.render for the interface and the arrays ``render`` returns. The
scene (camera with the spec's intrinsics, lights that move with the camera,
world, render settings) is built once per renderer and the mesh once per
instance; a frame only moves the camera and renders one multi-layer EXR
(Combined, Depth, Object Index) that is read back with the OpenEXR package.

Blender runs in worker processes only (spm_data.commands.render_jobs): a crash or a
leak in Blender takes down a worker, never the run.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
import warnings

import numpy as np

from spm_data.errors import RenderError
from spm_data.core.poses import K_to_corner_origin, cv_to_gl_camera_to_world
from spm_data.render import Renderer, light_rotations

NO_HIT_DEPTH = 1e9  # Blender writes 1e10 where no surface was hit
INSTALL_HINT = "install it with: pip install 'spm[blender]' (bpy 5.0.x, Python 3.11)"


def _import_bpy():
    try:
        import bpy
        import mathutils
    except ImportError as exc:
        raise RenderError(f"Blender's bpy module is not installed ({exc}); {INSTALL_HINT}") from None
    return bpy, mathutils


def _import_openexr():
    try:
        import OpenEXR
    except ImportError as exc:
        raise RenderError(f"the OpenEXR package is not installed ({exc}); {INSTALL_HINT}") from None
    return OpenEXR


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """Linear float RGB (any shape) -> sRGB uint8 (IEC 61966-2-1 transfer curve)."""
    c = np.clip(linear, 0.0, 1.0)
    s = np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1 / 2.4) - 0.055)
    return np.round(s * 255.0).astype(np.uint8)


@contextlib.contextmanager
def _captured_output(log_path: str):
    """Send the C-level stdout and stderr to ``log_path`` while Blender works.

    Blender prints a line per saved frame, and Workbench on Mesa's EGL an
    EGL_BAD_MATCH line per frame although its output is right (the agreement
    test checks it); a failing render quotes the log's tail instead.
    """
    saved = [os.dup(1), os.dup(2)]
    log = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    try:
        os.dup2(log, 1)
        os.dup2(log, 2)
        yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, log):
            os.close(fd)


def _tail(path: str, lines: int = 3) -> str:
    try:
        with open(path, errors="replace") as fh:
            return " | ".join(line.strip() for line in fh.readlines()[-lines:] if line.strip())
    except OSError:
        return ""


GPU_BACKENDS = ("OPTIX", "CUDA", "HIP", "ONEAPI", "METAL")  # in the order "auto" and "gpu" try them

class BlenderRenderer(Renderer):
    """bpy renderer for one spec (engine, samples, image size, intrinsics, lights)."""

    name = "blender"

    def __init__(self, spec):
        super().__init__(spec)
        self._bpy, self._mathutils = _import_bpy()
        self._exr = _import_openexr()
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
        try:
            with _captured_output(self._log):
                self._build_scene()
        except RenderError:
            raise
        except Exception as exc:  # bpy raises RuntimeError/TypeError for scene setup problems
            raise RenderError(f"Blender could not set up the scene ({exc}) {_tail(self._log)}".strip()) from None

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
        """Where Cycles renders, as the spec's ``device`` asks: ``"CPU"`` or the GPU backend
        used (OPTIX, CUDA, HIP, ONEAPI, METAL; the first with a device). ``"auto"`` falls
        back to the CPU; ``"gpu"`` without one is a RenderError."""
        wanted = self.spec.render.blender.device
        if self.engine != "cycles" or wanted == "cpu":
            sc.cycles.device = "CPU"
            return "CPU"
        prefs = self._bpy.context.preferences.addons["cycles"].preferences
        for backend in GPU_BACKENDS:
            try:
                prefs.compute_device_type = backend  # a TypeError where this Blender has no such backend
                found = [d for d in prefs.get_devices_for_type(backend) if d.type == backend]
            except (TypeError, AttributeError, RuntimeError):
                continue
            if found:
                for d in prefs.devices:
                    d.use = d.type == backend
                sc.cycles.device = "GPU"
                return backend
        if wanted == "gpu":
            raise RenderError("render.blender.device = \"gpu\": Blender finds no GPU here (tried "
                              f"{', '.join(GPU_BACKENDS)}); use \"auto\" to fall back to the CPU, or \"cpu\"")
        sc.cycles.device = "CPU"
        return "CPU"

    def _set_output(self, sc) -> None:
        """One multi-layer EXR a frame: Combined, Depth and Object Index, 32-bit, uncompressed."""
        layer = sc.view_layers[0]
        layer.use_pass_z = True
        layer.use_pass_object_index = True
        r = sc.render
        img = r.image_settings
        img.media_type = "MULTI_LAYER_IMAGE"
        img.file_format = "OPEN_EXR_MULTILAYER"
        img.color_depth = "32"
        img.exr_codec = "NONE"
        r.filepath = self._exr_path
        r.use_file_extension = False

    def _add_camera(self, sc) -> None:
        cam = self._bpy.data.cameras.new("spm-camera")
        K, W, H = self.K, self.width, self.height
        cam.sensor_fit = "HORIZONTAL"
        cam.sensor_width = 36.0
        cam.lens = K[0, 0] * cam.sensor_width / W
        # Blender's principal point sits at the image centre plus shift (in units of the larger side).
        cx, cy = K_to_corner_origin(K)[:2, 2]
        cam.shift_x = (W / 2.0 - cx) / max(W, H)
        cam.shift_y = (cy - H / 2.0) / max(W, H)
        cam.clip_start, cam.clip_end = 0.01, 100.0
        self._camera = self._bpy.data.objects.new("spm-camera", cam)
        sc.collection.objects.link(self._camera)
        sc.camera = self._camera

    def _add_lights(self, sc) -> None:
        """Suns parented to the camera (as the pyrender backend's lights move with it), and
        the ambient term as the world's colour."""
        bpy, lighting = self._bpy, self.spec.lighting
        for i, rot in enumerate(light_rotations(lighting.lights)):
            sun = bpy.data.lights.new(f"spm-sun-{i}", "SUN")
            sun.energy = lighting.strength
            obj = bpy.data.objects.new(f"spm-sun-{i}", sun)
            sc.collection.objects.link(obj)
            obj.parent = self._camera
            local = np.eye(4)
            local[:3, :3] = rot
            obj.matrix_basis = self._mathutils.Matrix(local.tolist())
        world = bpy.data.worlds.new("spm-world")
        sc.world = world
        if world.node_tree is None:  # Blender < 5 needs asking; 5.x always has nodes
            world.use_nodes = True
        background = world.node_tree.nodes.get("Background")
        a = lighting.ambient
        background.inputs["Color"].default_value = (a, a, a, 1.0)
        background.inputs["Strength"].default_value = 1.0

    def version(self) -> str:
        return f"Blender {self._bpy.app.version_string}"

    def settings(self) -> dict:
        s = self.spec.render.blender
        out = {"engine": self.engine, "film_transparent": s.film_transparent, "threads": s.threads,
               "ambient": self.spec.lighting.ambient, "lights": self.spec.lighting.lights,
               "strength": self.spec.lighting.strength}
        if self.engine == "cycles":
            out.update(samples=s.samples, denoise=s.denoise, filter_width=0.01, device=self.device)
        return out

    # ------------------------------------------------------------------ mesh
    def set_mesh(self, mesh) -> None:
        """Replace the object with ``mesh`` (a TexturedMesh): mesh data, UVs, normals, texture."""
        bpy = self._bpy
        if self._object is not None:
            old_mesh, old_mat = self._object.data, self._object.active_material
            old_image = old_mat.node_tree.nodes["spm-texture"].image if old_mat else None
            bpy.data.objects.remove(self._object)
            bpy.data.meshes.remove(old_mesh)
            if old_mat:
                bpy.data.materials.remove(old_mat)
            if old_image:
                bpy.data.images.remove(old_image)
        me = bpy.data.meshes.new(mesh.name)
        me.from_pydata(mesh.vertices.tolist(), [], mesh.faces.tolist())
        # Vertices are per face corner (meshes.py), so loop i is vertex i.
        uv_layer = me.uv_layers.new(name="UVMap")
        uv_layer.data.foreach_set("uv", mesh.uv.astype(np.float32).ravel())
        me.polygons.foreach_set("use_smooth", np.ones(len(mesh.faces), dtype=bool))
        me.normals_split_custom_set_from_vertices(mesh.normals.tolist())
        me.update()

        h, w = mesh.texture.shape[:2]
        image = bpy.data.images.new(f"{mesh.name}-texture", width=w, height=h, alpha=False)
        rgba = np.ones((h, w, 4), dtype=np.float32)
        rgba[..., :3] = mesh.texture[::-1] / 255.0  # Blender's pixel rows start at the bottom
        image.pixels.foreach_set(rgba.ravel())
        image.pack()

        mat = bpy.data.materials.new(f"{mesh.name}-material")
        if mat.node_tree is None:
            mat.use_nodes = True
        nodes = mat.node_tree.nodes
        bsdf = nodes.get("Principled BSDF")
        tex = nodes.new("ShaderNodeTexImage")
        tex.name = "spm-texture"
        tex.image = image
        mat.node_tree.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
        bsdf.inputs["Roughness"].default_value = 0.9
        bsdf.inputs["Metallic"].default_value = 0.0
        me.materials.append(mat)

        obj = bpy.data.objects.new(mesh.name, me)
        obj.pass_index = 1
        bpy.context.scene.collection.objects.link(obj)
        self._object = obj

    # ------------------------------------------------------------------ frames
    def render(self, R, t) -> dict:
        if self._object is None:
            raise RenderError("set_mesh must be called before render")
        self._camera.matrix_world = self._mathutils.Matrix(cv_to_gl_camera_to_world(R, t).tolist())
        try:
            with _captured_output(self._log):
                self._bpy.ops.render.render(write_still=True)
        except RuntimeError as exc:
            raise RenderError(f"Blender failed to render a frame ({exc}) {_tail(self._log)}".strip()) from None
        return self._read_exr()

    def _read_exr(self) -> dict:
        try:
            with self._exr.File(self._exr_path) as f:
                # Blender 5 writes one EXR part per pass.
                channels = {name: ch for part in f.parts for name, ch in part.channels.items()}
                combined = np.asarray(channels["ViewLayer.Combined"].pixels, dtype=np.float32)
                z = np.asarray(channels["ViewLayer.Depth.Z"].pixels, dtype=np.float32)
                index = channels.get("ViewLayer.Object Index.X")
                index = None if index is None else np.asarray(index.pixels)
        except (OSError, KeyError, RuntimeError) as exc:
            raise RenderError(f"could not read Blender's EXR output ({type(exc).__name__}: {exc})") from None
        hit = z < NO_HIT_DEPTH
        mask = (index > 0.5) & hit if index is not None else hit
        depth = np.where(mask, z, 0.0).astype(np.float32)
        alpha = np.clip(combined[..., 3], 0.0, 1.0)
        return {"rgb": srgb_encode(combined[..., :3]), "alpha": alpha.astype(np.float32),
                "depth": depth, "mask": mask.astype(np.uint8)}

    def close(self) -> None:
        shutil.rmtree(self._tmp, ignore_errors=True)
