"""pyrender (OpenGL, offscreen EGL) renderer: the fast backend.

See spm_data.render.base for the interface and the arrays ``render`` returns.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import time

import numpy as np

from spm_data.errors import RenderError
from spm_data.core.poses import K_to_corner_origin, cv_to_gl_camera_to_world
from spm_data.core.raster import CLIP_FAR, CLIP_NEAR
from spm_data.render import base
from spm_data.render.base import Renderer, assigned_gpu, decode_normals, light_rotations, mask_from_depth

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
    if not getattr(gl_renderer, "_spm_timed_readback", False):
        gl_renderer.Renderer._read_main_framebuffer = _timed_readback(gl_renderer)
        gl_renderer._spm_timed_readback = True
    return pyrender


_READBACK = [0.0]  # seconds this process spent reading frames back (render_shard's split)


def _timed_readback(gl_renderer):
    """pyrender's read of a drawn frame, timed: the copy and the wait for the drawing to end (a
    GPU draws while Python goes on; llvmpipe draws only when the frame is first read), so a large
    readback says the drawing bounds the loop. No glFinish to split the two: on llvmpipe that
    is one more wait for its threads (0-5% of a 128x128 frame here)."""
    read = gl_renderer.Renderer._read_main_framebuffer

    def timed(self, scene, flags):
        started = time.perf_counter()
        try:
            return read(self, scene, flags)
        finally:
            _READBACK[0] += time.perf_counter() - started
    return timed


# --------------------------------------------------------------------------- GPUs (EGL devices)

EGL_EXTENSIONS = 0x3055  # eglQueryDeviceStringEXT: the device's extensions
SOFTWARE_DEVICE = "EGL_MESA_device_software"  # Mesa's llvmpipe, listed among EGL's devices


def gpu_devices(extensions) -> list[int]:
    """Indices into EGL's device list (pyrender's EGL_DEVICE_ID) of the GPUs, given each EGL
    device's extension string: every device but software renderers, in EGL's order. GPU k
    (``--gpus k``) is the k-th of them."""
    return [i for i, ext in enumerate(extensions) if SOFTWARE_DEVICE not in str(ext).split()]


def egl_device_id(gpu, extensions) -> int | None:
    """pyrender's EGL_DEVICE_ID for GPU ``gpu`` (None: the first GPU; without one, None: EGL's
    default display); RenderError (one line) for a GPU that EGL does not list."""
    devices = gpu_devices(extensions)
    if gpu is None:
        return devices[0] if devices else None
    if gpu >= len(devices):
        listed = f"GPUs 0-{len(devices) - 1}" if devices else "no GPU, only a software renderer"
        raise RenderError(f"pyrender: there is no GPU {gpu} here; EGL lists {listed}")
    return devices[gpu]


def _egl_extensions() -> list[str]:
    """Each EGL device's extension string, in EGL's order (the order pyrender's EGL_DEVICE_ID
    counts in: the same eglQueryDevicesEXT of the same libEGL); [] where EGL is not pyrender's
    platform or cannot list its devices. Through ctypes, so that a run's parent process lists
    the GPUs in milliseconds, without importing pyrender and OpenGL (over a second)."""
    if os.environ.get("PYOPENGL_PLATFORM") != "egl":
        return []
    try:
        lib = ctypes.CDLL(ctypes.util.find_library("EGL") or "libEGL.so.1")
        lib.eglGetProcAddress.restype, lib.eglGetProcAddress.argtypes = ctypes.c_void_p, [ctypes.c_char_p]
        query, string = (lib.eglGetProcAddress(name) for name in (b"eglQueryDevicesEXT", b"eglQueryDeviceStringEXT"))
        if not query or not string:  # no EGL_EXT_device_enumeration: only the default display
            return []
        query = ctypes.CFUNCTYPE(ctypes.c_uint, ctypes.c_int, ctypes.POINTER(ctypes.c_void_p),
                                 ctypes.POINTER(ctypes.c_int))(query)
        string = ctypes.CFUNCTYPE(ctypes.c_char_p, ctypes.c_void_p, ctypes.c_int)(string)
        devices, count = (ctypes.c_void_p * 64)(), ctypes.c_int(0)  # 64: more than any machine has
        if not query(64, devices, ctypes.byref(count)):
            return []
        return [(string(device, EGL_EXTENSIONS) or b"").decode() for device in devices[:count.value]]
    except (OSError, AttributeError):  # no libEGL here
        return []


def visible_gpus() -> tuple[tuple[int, ...], str]:
    """(GPU indices, who lists them) in this process: the EGL devices that are not software."""
    return tuple(range(len(gpu_devices(_egl_extensions())))), "pyrender's EGL"


def _choose_device() -> None:
    """Point pyrender (EGL_DEVICE_ID, read as a context is opened) at this worker's GPU
    (base.assigned_gpu), or at the first GPU: EGL's device 0 may be a software renderer. A
    user's own EGL_DEVICE_ID stands when no GPU was assigned."""
    gpu = assigned_gpu()
    device = None if gpu is None and "EGL_DEVICE_ID" in os.environ else egl_device_id(gpu, _egl_extensions())
    if device is not None:
        os.environ["EGL_DEVICE_ID"] = str(device)


_OFFSCREEN: dict = {}
_SCENE_CLASS = None


def _one_blas_thread() -> None:
    """Keep this process's BLAS on one thread. pyrender inverts a 4x4 matrix per frame
    (np.linalg.inv), which wakes OpenBLAS's threads, and they then spin in sched_yield
    waiting for more: measured 3-4.7 ms of CPU a frame of a 5-7 ms frame on 2 cores, taken
    from llvmpipe and the shard writer. The same pixels (the products are 4x4; shards
    compared byte for byte). Not restored: the limit stays with the process, as its renderer."""
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")


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
        _choose_device()
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
        _one_blas_thread()
        self.lighting = spec.lighting
        try:
            self._renderer = _offscreen(self._pr, self.width, self.height)
        except RenderError:
            raise
        except Exception as exc:  # EGL / driver failures surface as many types
            raise RenderError(f"pyrender could not open an offscreen EGL context ({type(exc).__name__}: {exc}); "
                              "install Mesa's EGL (apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri)") from None
        side = max_image_side(self._renderer)
        if side is not None and max(self.width, self.height) > side:
            raise RenderError(f"pyrender: image {self.width}x{self.height} is larger than this OpenGL renders "
                              f"({side} pixels a side at most); use a smaller image or the blender renderer")
        self._scene = None
        self._distractor_meshes = {}  # id(mesh) -> (mesh, its pyrender meshes), built once per distractor mesh
        self._target = ()

    @property
    def readback_seconds(self) -> float:
        return _READBACK[0]

    def gl_renderer(self) -> str:
        """The OpenGL renderer this process draws with (GL_RENDERER: "llvmpipe (LLVM 15.0.7, 256
        bits)" on the CPU, the GPU's name otherwise), for benchmarks."""
        from OpenGL import GL

        self._renderer._platform.make_current()
        return GL.glGetString(GL.GL_RENDERER).decode()

    def version(self) -> str:
        return f"pyrender {self._pr.__version__ if hasattr(self._pr, '__version__') else ''}".strip()

    def settings(self) -> dict:
        return self.lighting_settings()

    def _pyrender_meshes(self, mesh):
        """(lit, normals) pyrender meshes of ``mesh``: the textured one, and, when the spec
        asks for normals, one whose vertex colours are its object-frame normals (n + 1) / 2."""
        pr = self._pr
        positions, indices = mesh.vertices.astype(np.float32), mesh.faces.astype(np.uint32)
        normals = mesh.normals.astype(np.float32)
        texture = pr.Texture(source=mesh.texture, source_channels="RGB")
        material = pr.MetallicRoughnessMaterial(baseColorTexture=texture, metallicFactor=0.0,
                                                roughnessFactor=0.9, doubleSided=True)
        lit = pr.Mesh(primitives=[pr.Primitive(positions=positions, normals=normals, indices=indices, material=material,
                                               texcoord_0=mesh.uv.astype(np.float32))])
        if not self.outputs.normals:
            return (lit,)
        plain = pr.MetallicRoughnessMaterial(baseColorFactor=[1.0, 1.0, 1.0, 1.0], doubleSided=True)
        coded = pr.Mesh(primitives=[pr.Primitive(positions=positions, normals=normals, indices=indices,
                                                 color_0=(normals + 1.0) / 2.0, material=plain)], is_visible=False)
        return lit, coded

    def _distractor(self, mesh):
        if id(mesh) not in self._distractor_meshes:  # the mesh is kept, so its id stays its own
            self._distractor_meshes[id(mesh)] = (mesh, self._pyrender_meshes(mesh))
        return self._distractor_meshes[id(mesh)][1]

    def set_mesh(self, mesh) -> None:
        """Build the scene for ``mesh`` (a TexturedMesh); later frames only move the camera."""
        pr = self._pr
        self._target = self._pyrender_meshes(mesh)
        a = self.lighting.ambient
        scene = _ordered_scene_class(pr)(bg_color=[0.0, 0.0, 0.0, 0.0], ambient_light=[a, a, a])
        self._target_nodes = [scene.add(m) for m in self._target]
        self._material = self._target[0].primitives[0].material
        K = K_to_corner_origin(self.K)  # pyrender counts the principal point from the pixel corner
        self._camera = pr.IntrinsicsCamera(K[0, 0], K[1, 1], K[0, 2], K[1, 2], znear=CLIP_NEAR, zfar=CLIP_FAR)
        self._camera_node = scene.add(self._camera, pose=np.eye(4))
        self._light_nodes = [scene.add(pr.DirectionalLight(color=np.ones(3), intensity=self.lighting.strength),
                                       name=f"spm-light-{i}", pose=np.eye(4)) for i in range(self.max_lights)]
        self._light_rots = light_rotations(self.lighting.lights)
        self._scene = scene

    def _apply_draws(self, draws) -> None:
        """Set the frame's intrinsics, lights, ambient light and material (FrameDraws)."""
        K = K_to_corner_origin(draws.K)
        self._camera.fx, self._camera.fy, self._camera.cx, self._camera.cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
        for i, node in enumerate(self._light_nodes):
            lit = i < len(draws.light_strengths)
            node.light.color = draws.light_colors[i] if lit else np.ones(3)
            node.light.intensity = float(draws.light_strengths[i]) if lit else 0.0
        self._scene.ambient_light = np.full(3, draws.ambient)
        self._material.baseColorFactor = np.array([*draws.base_color, 1.0])
        self._material.roughnessFactor, self._material.metallicFactor = draws.roughness, draws.metallic

    def render(self, R, t, draws=None, distractors=()) -> dict:
        if self._scene is None:
            raise RenderError("set_mesh must be called before render")
        if draws is not None:
            self._apply_draws(draws)
        pose = cv_to_gl_camera_to_world(R, t)
        self._scene.set_pose(self._camera_node, pose)
        rotations = draws.light_rotations if draws is not None else self._light_rots
        for node, rot in zip(self._light_nodes, rotations):
            light_pose = pose.copy()
            light_pose[:3, :3] = pose[:3, :3] @ rot
            self._scene.set_pose(node, light_pose)
        added = self._add_distractors(R, t, distractors)
        try:
            return self._render_passes(R, distractors, added)
        finally:
            for nodes in added:
                for node in nodes:
                    self._scene.remove_node(node)

    def _add_distractors(self, R, t, distractors) -> list:
        """Add each PlacedDistractor's nodes, posed in the target's (the world's) frame."""
        world_from_camera = np.eye(4)
        world_from_camera[:3, :3], world_from_camera[:3, 3] = R.T, -R.T @ t
        added = []
        for d in distractors:
            pose = world_from_camera @ d.matrix()
            added.append([self._scene.add(m, pose=pose) for m in self._distractor(d.mesh)])
        return added

    def _render_passes(self, R, distractors, added) -> dict:
        pr, flags = self._pr, self._pr.RenderFlags.SKIP_CULL_FACES
        color, depth = self._renderer.render(self._scene, flags=flags)
        depth = np.asarray(depth, dtype=np.float32)
        out = {"rgb": np.ascontiguousarray(color[..., :3], dtype=np.uint8), "depth": depth}
        if distractors or self.outputs.instances or self.outputs.normals:
            ids = {node: k + 1 for k, nodes in enumerate([self._target_nodes, *added]) for node in nodes}
            seg, seg_depth = self._renderer.render(self._scene, flags=flags | pr.RenderFlags.SEG,
                                                   seg_node_map={node: [k, k, k] for node, k in ids.items()})
            out["instances"] = base.labels_agreeing_with_depth(seg[..., 0], depth, np.asarray(seg_depth, np.float32))
            mask = (out["instances"] == 1).astype(np.uint8)
        else:
            mask = mask_from_depth(depth)
        out["alpha"], out["mask"] = (depth > 0).astype(np.float32), mask
        if self.outputs.normals:
            out["normals"] = self._normals_pass(R, distractors, out["instances"])
        return out

    def _normals_pass(self, R, distractors, instances) -> np.ndarray:
        """(H, W, 3) float32 camera-frame unit normals: the normal-coloured meshes drawn flat."""
        pr = self._pr
        pairs = [self._target] + [meshes for _, meshes in self._distractor_meshes.values()]
        for lit, coded in pairs:
            lit.is_visible, coded.is_visible = False, True
        try:
            coded_rgb, _ = self._renderer.render(self._scene,
                                                 flags=pr.RenderFlags.SKIP_CULL_FACES | pr.RenderFlags.FLAT)
        finally:
            for lit, coded in pairs:
                lit.is_visible, coded.is_visible = True, False
        rotations = np.stack([np.eye(3), R, *[d.R for d in distractors]])  # by instance id; 0: nothing
        return decode_normals(coded_rgb[..., :3], instances, rotations)

    def close(self) -> None:
        """Drop the scene; the shared GL context lives until the process exits."""
        self._scene = None
