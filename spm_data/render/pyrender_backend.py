"""pyrender (OpenGL, offscreen EGL) renderer: the fast backend.

See spm_data.render for the interface and the arrays ``render`` returns.
"""

from __future__ import annotations

import os

import numpy as np

from spm_data.errors import RenderError
from spm_data.core.poses import K_to_corner_origin, cv_to_gl_camera_to_world
from spm_data.render import Renderer, light_rotations, mask_from_depth

# EGL needs no display; it must be chosen before OpenGL is first imported.
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")


def _import_pyrender():
    try:
        import pyrender
        import pyrender.renderer as gl_renderer
    except ImportError as exc:
        raise RenderError(f"pyrender is not installed ({exc}); install it with: pip install pyrender") from None
    # pyrender draws into a 4x multisampled buffer and resolves depth with a
    # NEAREST blit, which returns sample 0 (about 0.4 px off the pixel centre)
    # instead of the pixel centre K describes. One sample per pixel keeps depth,
    # mask and the label exactly consistent (tests/render/test_pyrender_backend.py).
    if not getattr(gl_renderer, "_spm_single_sample", False):
        multisample = gl_renderer.glRenderbufferStorageMultisample
        gl_renderer.glRenderbufferStorageMultisample = (
            lambda target, samples, fmt, width, height: multisample(target, 0, fmt, width, height))
        gl_renderer._spm_single_sample = True
    return pyrender


_OFFSCREEN: dict = {}
_SCENE_CLASS = None


def _ordered_scene_class(pr):
    """pyrender.Scene whose lights come back in name order. pyrender keeps light
    nodes in sets, iterated in an order that follows object addresses and so
    varies between processes; the shader then sums the lights in another order
    and a pixel can come out one level apart. A fixed order makes renders
    repeat bit for bit (tests/system/test_reliability.py)."""
    global _SCENE_CLASS
    if _SCENE_CLASS is None:
        class OrderedLightScene(pr.Scene):
            @property
            def light_nodes(self):
                return sorted(super().light_nodes, key=lambda n: n.name or "")

        _SCENE_CLASS = OrderedLightScene
    return _SCENE_CLASS


def _offscreen(pr, width: int, height: int):
    """One OffscreenRenderer per size per process, never deleted: deleting one
    calls eglTerminate on the display every other EGL context shares."""
    key = (width, height)
    if key not in _OFFSCREEN:
        _OFFSCREEN[key] = pr.OffscreenRenderer(width, height)
    return _OFFSCREEN[key]


_MAX_SIDE: list = []


def max_image_side(offscreen) -> int | None:
    """The largest image side this process's OpenGL can render into (the smaller of
    GL_MAX_RENDERBUFFER_SIZE and GL_MAX_VIEWPORT_DIMS; 16384 on Mesa's llvmpipe),
    or None when the driver does not say."""
    if not _MAX_SIDE:
        try:
            from OpenGL import GL

            offscreen._platform.make_current()
            sides = [int(GL.glGetIntegerv(GL.GL_MAX_RENDERBUFFER_SIZE)),
                     *(int(v) for v in GL.glGetIntegerv(GL.GL_MAX_VIEWPORT_DIMS))]
            _MAX_SIDE.append(min(sides) if min(sides) > 0 else None)
        except Exception:  # noqa: BLE001 - no answer is no limit; a real failure shows at render
            _MAX_SIDE.append(None)
    return _MAX_SIDE[0]


class PyrenderRenderer(Renderer):
    """pyrender offscreen renderer for one spec (image size, intrinsics, lights)."""

    name = "pyrender"

    def __init__(self, spec):
        super().__init__(spec)
        self._pr = _import_pyrender()
        self.lighting = spec.lighting
        try:
            self._renderer = _offscreen(self._pr, self.width, self.height)
        except Exception as exc:  # EGL / driver failures surface as many types
            raise RenderError(f"pyrender could not open an offscreen EGL context ({type(exc).__name__}: {exc}); "
                              "install Mesa's EGL (apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri)") from None
        side = max_image_side(self._renderer)
        if side is not None and max(self.width, self.height) > side:
            raise RenderError(f"pyrender: image {self.width}x{self.height} is larger than this OpenGL renders "
                              f"({side} pixels a side at most); use a smaller image or the blender renderer")
        self._scene = None

    def version(self) -> str:
        return f"pyrender {self._pr.__version__ if hasattr(self._pr, '__version__') else ''}".strip()

    def settings(self) -> dict:
        return {"ambient": self.lighting.ambient, "lights": self.lighting.lights,
                "strength": self.lighting.strength}

    def set_mesh(self, mesh) -> None:
        """Build the scene for ``mesh`` (a TexturedMesh); later frames only move the camera."""
        pr = self._pr
        texture = pr.Texture(source=mesh.texture, source_channels="RGB")
        material = pr.MetallicRoughnessMaterial(baseColorTexture=texture, metallicFactor=0.0,
                                                roughnessFactor=0.9, doubleSided=True)
        primitive = pr.Primitive(positions=mesh.vertices.astype(np.float32), normals=mesh.normals.astype(np.float32),
                                 texcoord_0=mesh.uv.astype(np.float32), indices=mesh.faces.astype(np.uint32),
                                 material=material)
        a = self.lighting.ambient
        scene = _ordered_scene_class(pr)(bg_color=[0.0, 0.0, 0.0, 0.0], ambient_light=[a, a, a])
        scene.add(pr.Mesh(primitives=[primitive]))
        K = K_to_corner_origin(self.K)  # pyrender counts the principal point from the pixel corner
        camera = pr.IntrinsicsCamera(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2],
                                     znear=0.01, zfar=100.0)
        self._camera_node = scene.add(camera, pose=np.eye(4))
        self._light_nodes = [scene.add(pr.DirectionalLight(color=np.ones(3), intensity=self.lighting.strength),
                                       name=f"spm-light-{i}", pose=np.eye(4)) for i in range(self.lighting.lights)]
        self._light_rots = light_rotations(self.lighting.lights)
        self._scene = scene

    def render(self, R, t) -> dict:
        if self._scene is None:
            raise RenderError("set_mesh must be called before render")
        pose = cv_to_gl_camera_to_world(R, t)
        self._scene.set_pose(self._camera_node, pose)
        for node, rot in zip(self._light_nodes, self._light_rots):
            light_pose = pose.copy()
            light_pose[:3, :3] = pose[:3, :3] @ rot
            self._scene.set_pose(node, light_pose)
        flags = self._pr.RenderFlags.SKIP_CULL_FACES
        color, depth = self._renderer.render(self._scene, flags=flags)
        depth = np.asarray(depth, dtype=np.float32)
        mask = mask_from_depth(depth)
        return {"rgb": np.ascontiguousarray(color[..., :3], dtype=np.uint8), "alpha": mask.astype(np.float32),
                "depth": depth, "mask": mask}

    def close(self) -> None:
        """Drop the scene; the shared GL context lives until the process exits."""
        self._scene = None
