"""Blender helpers that need no renderer state: meshes and materials from a
TexturedMesh, Blender's console output captured, linear to sRGB (spm_data.render.blender)."""

from __future__ import annotations

import contextlib
import os

import numpy as np


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """Linear float RGB (any shape) -> sRGB uint8 (IEC 61966-2-1 transfer curve)."""
    c = np.clip(linear, 0.0, 1.0)
    s = np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1 / 2.4) - 0.055)
    return np.round(s * 255.0).astype(np.uint8)


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
