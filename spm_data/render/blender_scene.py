"""Blender helpers that need no renderer state (spm_data.render.blender): meshes and
materials from a TexturedMesh, the Cycles device, the render border and its uncropping,
Blender's console output captured, linear to sRGB."""

from __future__ import annotations

import contextlib
import os

import numpy as np

from spm_data.errors import RenderError


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """Linear float RGB (any shape) -> sRGB uint8 (IEC 61966-2-1 transfer curve).

    Only values above 0 go through the curve (a frame is mostly background, which
    is exactly 0 and encodes to 0); each value's code is the same as through the
    curve for the whole array."""
    c = np.clip(linear, 0.0, 1.0)
    out = np.zeros(c.shape, dtype=np.uint8)
    lit = c > 0.0
    v = c[lit]
    s = np.where(v <= 0.0031308, 12.92 * v, 1.055 * np.power(v, 1 / 2.4) - 0.055)
    out[lit] = np.round(s * 255.0).astype(np.uint8)
    return out


BORDER_MARGIN = 2  # pixels kept around the projected geometry


def border_box(points, K, width: int, height: int, margin: int = BORDER_MARGIN):
    """The pixels ``(x0, y0, x1, y1)`` (half-open) around camera-frame ``points`` (N, 3)
    metres projected through ``K`` (3, 3, OpenCV centres), plus ``margin``; None when a
    point is at or behind the camera plane, nothing is given, or the box is the frame."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if not len(p) or p[:, 2].min() <= 1e-6:
        return None
    uv = p @ np.asarray(K, dtype=np.float64).T
    u, v = uv[:, 0] / uv[:, 2], uv[:, 1] / uv[:, 2]  # OpenCV: pixel i's centre is at i
    x0, x1 = max(0, int(np.floor(u.min())) - margin), min(width, int(np.floor(u.max())) + margin + 1)
    y0, y1 = max(0, int(np.floor(v.min())) - margin), min(height, int(np.floor(v.max())) + margin + 1)
    if x0 >= x1 or y0 >= y1 or (x1 - x0) * (y1 - y0) == width * height:
        return None
    return x0, y0, x1, y1


def uncrop(arrays: dict, crop, height: int, width: int) -> dict:
    """Arrays of a render border ``crop`` = (x0, y0, x1, y1) placed in frames of zeros, the
    background a full frame has with a transparent film (rgb, alpha, depth, ids, normals 0)."""
    x0, y0, x1, y1 = crop
    full = {}
    for name, a in arrays.items():
        full[name] = np.zeros((height, width) + a.shape[2:], dtype=a.dtype)
        full[name][y0:y1, x0:x1] = a
    return full


@contextlib.contextmanager
def captured_output(log_path: str):
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


def tail(path: str, lines: int = 3) -> str:
    try:
        with open(path, errors="replace") as fh:
            return " | ".join(line.strip() for line in fh.readlines()[-lines:] if line.strip())
    except OSError:
        return ""


def remove_mesh_data(bpy, me) -> None:
    """Remove a Blender mesh made by mesh_data, with its material and image."""
    mat = me.materials[0] if me.materials else None
    image = mat.node_tree.nodes["spm-texture"].image if mat else None
    bpy.data.meshes.remove(me)
    if mat:
        bpy.data.materials.remove(mat)
    if image:
        bpy.data.images.remove(image)

def mesh_data(bpy, mesh, base_color: bool = False):
    """A Blender mesh of ``mesh`` with its textured material; ``base_color``: a
    multiply node (``spm-base-color``) between texture and BSDF for the jitter."""
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
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = nodes.get("Principled BSDF")
    tex = nodes.new("ShaderNodeTexImage")
    tex.name = "spm-texture"
    tex.image = image
    if base_color:
        mix = nodes.new("ShaderNodeMix")
        mix.name, mix.data_type, mix.blend_type = "spm-base-color", "RGBA", "MULTIPLY"
        mix.inputs["Factor"].default_value = 1.0
        links.new(tex.outputs["Color"], mix.inputs["A"])
        links.new(mix.outputs["Result"], bsdf.inputs["Base Color"])
    else:
        links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    bsdf.inputs["Roughness"].default_value = 0.9
    bsdf.inputs["Metallic"].default_value = 0.0
    me.materials.append(mat)
    return me


GPU_BACKENDS = ("OPTIX", "CUDA", "HIP", "ONEAPI", "METAL")  # in the order "auto" and "gpu" try them


def cycles_device(bpy, sc, wanted: str, gpu: int | None = None) -> str:
    """Where Cycles renders, as a spec's ``render.blender.device`` (``wanted``) asks:
    ``"CPU"`` or the GPU backend used (OPTIX, CUDA, HIP, ONEAPI, METAL; the first with a
    device). ``"auto"`` falls back to the CPU; ``"gpu"`` without one is a RenderError.
    ``gpu``: the worker's GPU (--gpus; base.assigned_gpu), the only device Cycles then uses,
    counted in that backend's device list; None: every device of the backend."""
    if wanted == "cpu":
        sc.cycles.device = "CPU"
        return "CPU"
    prefs = bpy.context.preferences.addons["cycles"].preferences
    for backend in GPU_BACKENDS:
        try:
            prefs.compute_device_type = backend  # a TypeError where this Blender has no such backend
            found = [d for d in prefs.get_devices_for_type(backend) if d.type == backend]
        except (TypeError, AttributeError, RuntimeError):
            continue
        if found:
            use = pick_device(found, gpu, backend)
            for d in prefs.devices:
                d.use = d.type == backend and (use is None or d.id == use.id)
            sc.cycles.device = "GPU"
            return backend
    if wanted == "gpu":
        raise RenderError("render.blender.device = \"gpu\": Blender finds no GPU here (tried "
                          f"{', '.join(GPU_BACKENDS)}); use \"auto\" to fall back to the CPU, or \"cpu\"")
    if gpu is not None:  # --gpus asked for one: "auto" does not fall back to the CPU then
        raise RenderError(f"--gpus {gpu}: Blender finds no GPU here (tried {', '.join(GPU_BACKENDS)}); "
                          "leave --gpus out to render on the CPU")
    sc.cycles.device = "CPU"
    return "CPU"


def pick_device(found: list, gpu: int | None, backend: str):
    """The device of ``found`` (one backend's, in Blender's order) that --gpus gave this worker,
    or None (all of them); RenderError (one line) for a GPU Blender does not list."""
    if gpu is None:
        return None
    if gpu >= len(found):
        raise RenderError(f"--gpus: there is no GPU {gpu} for Blender; it lists {len(found)} {backend} "
                          f"device{'s' if len(found) != 1 else ''} (0-{len(found) - 1})")
    return found[gpu]
