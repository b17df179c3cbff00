"""The pyrender backend against geometry computed independently from K, R, t and the mesh."""

import numpy as np
import pytest

from spm_data.core.shapes import procedural_mesh
from spm_data.core.paths import AngleRange, CameraGrid, camera_path
from spm_data.core.poses import project_points
from spm_data.render import make_renderer
from spm_data.render.base import spec_intrinsics
from spm_data.core.specs import parse_spec
from spm_data.pipelines.render_jobs import load_run_specs


def ray_depths(mesh, K, R, t, pixels):
    """z-depth of the first hit of each pixel's ray (Moller-Trumbore, all triangles)."""
    tri = mesh.vertices[mesh.faces] @ R.T + t  # camera frame
    v0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    rays = np.column_stack([pixels[:, 0], pixels[:, 1], np.ones(len(pixels))]) @ np.linalg.inv(K).T
    out = np.full(len(pixels), np.inf)
    for i, d in enumerate(rays):
        p = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, p)
        ok = np.abs(det) > 1e-12
        inv = np.where(ok, 1.0 / np.where(ok, det, 1), 0)
        s = -v0
        u = np.einsum("ij,ij->i", s, p) * inv
        q = np.cross(s, e1)
        v = (q @ d) * inv
        dist = np.einsum("ij,ij->i", e2, q) * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (dist > 0)
        if hit.any():
            out[i] = dist[hit].min() * d[2]  # ray parameter times its z component = z depth
    return out


@pytest.fixture(scope="module")
def renderer():
    spec = parse_spec('class = "cup"\n[image]\nwidth = 64\nheight = 48\nfov = 40')
    r = make_renderer(spec, "pyrender")
    yield r, spec
    r.close()


@pytest.mark.parametrize("cls", ["cup", "car", "animal4"])
def test_mask_and_depth_match_ray_casting_the_mesh(renderer, cls):
    """Mask = pixels whose centre ray hits the mesh; depth = that hit's z; vertices land in the mask."""
    r, spec = renderer
    mesh = procedural_mesh(cls, 1)
    r.set_mesh(mesh)
    K = spec_intrinsics(spec)
    path = camera_path(CameraGrid(azimuth=AngleRange(0, 300, 60), elevation=AngleRange(0, 60, 30),
                                  distances=(0.6, 0.8), look_at=(0.01, -0.02, 0.0)))
    rows, cols = np.mgrid[0:48, 0:64]
    pixels = np.column_stack([cols.ravel(), rows.ravel()]).astype(float)
    for i in range(0, len(path), 6):
        R, t = path.poses(slice(i, i + 1))
        out = r.render(R[0], t[0])
        mask, depth = out["mask"], out["depth"]
        assert out["rgb"].shape == (48, 64, 3) and depth.dtype == np.float32 and mask.dtype == np.uint8
        np.testing.assert_array_equal(mask, (depth > 0).astype(np.uint8))
        expect = ray_depths(mesh, K, R[0], t[0], pixels).reshape(48, 64)
        hit = np.isfinite(expect)
        assert mask.sum() > 100
        # Pixel centres exactly on an edge may go either way: allow a handful.
        assert (hit != mask.astype(bool)).sum() <= 3
        both = hit & (mask > 0)
        rel = np.abs(depth[both] - expect[both]) / expect[both]
        assert np.median(rel) < 1e-5 and np.mean(rel < 1e-4) >= 0.98  # edge ties at depth steps
        uv, z = project_points(mesh.vertices, K, R[0], t[0])
        assert np.all(z > 0)
        c, rr = np.round(uv[:, 0]).astype(int), np.round(uv[:, 1]).astype(int)
        assert np.all((c >= 0) & (c < 64) & (rr >= 0) & (rr < 48))
        padded = np.pad(mask, 1)
        near = np.zeros(mask.shape, dtype=bool)
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                near |= padded[1 + dr:49 + dr, 1 + dc:65 + dc] > 0
        assert near[rr, c].all()


def test_sphere_on_the_axis_is_centred_on_the_principal_point(renderer):
    import trimesh

    from spm_data.core.meshes import to_textured

    r, spec = renderer
    r.set_mesh(to_textured(trimesh.creation.icosphere(5), "s", 0.25, np.random.default_rng(0)))
    R, t = camera_path(CameraGrid()).poses(slice(40, 41))
    ys, xs = np.nonzero(r.render(R[0], t[0])["mask"])
    K = spec_intrinsics(spec)
    np.testing.assert_allclose([xs.mean(), ys.mean()], K[:2, 2], atol=0.02)


def test_scene_is_built_once_and_frames_repeat_exactly(renderer):
    r, spec = renderer
    r.set_mesh(procedural_mesh("box", 0))
    R, t = camera_path(CameraGrid()).poses(slice(5, 6))
    a = r.render(R[0], t[0])
    b = r.render(R[0], t[0])
    for key in ("rgb", "depth", "mask"):
        np.testing.assert_array_equal(a[key], b[key])


def test_pyrender_refuses_an_image_larger_than_its_opengl(small_specs_dir, monkeypatch):
    from spm_data.errors import RenderError
    from spm_data.render import make_renderer, pyrender_backend

    spec = load_run_specs(["cup"], specs_dir=small_specs_dir)[0]
    offscreen = pyrender_backend._offscreen(pyrender_backend._import_pyrender(), 64, 64)
    assert pyrender_backend.max_image_side(offscreen) >= 64  # 16384 on Mesa llvmpipe
    monkeypatch.setattr(pyrender_backend, "_MAX_SIDE", [48])
    with pytest.raises(RenderError, match=r"^pyrender: image 64x64 is larger than this OpenGL renders \(48 pixels "
                                          r"a side at most\); use a smaller image or the blender renderer$"):
        make_renderer(spec)


# --------------------------------------------------------------------------- GPUs, timing, BLAS

EGL_LIST = ["EGL_MESA_device_software EGL_EXT_device_drm_render_node",   # llvmpipe first, as glvnd may list it
            "EGL_NV_device_cuda EGL_EXT_device_drm", "EGL_EXT_device_drm EGL_EXT_device_drm_render_node"]


def test_gpus_are_the_egl_devices_that_are_not_software():
    from spm_data.errors import RenderError
    from spm_data.render.pyrender_backend import egl_device_id, gpu_devices

    assert gpu_devices(EGL_LIST) == [1, 2] and gpu_devices(EGL_LIST[:1]) == [] and gpu_devices([]) == []
    assert egl_device_id(0, EGL_LIST) == 1 and egl_device_id(1, EGL_LIST) == 2
    assert egl_device_id(None, EGL_LIST) == 1       # no GPU assigned: the first GPU, not EGL's device 0
    assert egl_device_id(None, EGL_LIST[:1]) is None  # the CPU: EGL's default display
    with pytest.raises(RenderError, match=r"^pyrender: there is no GPU 2 here; EGL lists GPUs 0-1$"):
        egl_device_id(2, EGL_LIST)
    with pytest.raises(RenderError, match=r"^pyrender: there is no GPU 0 here; EGL lists no GPU, only a software "
                                          r"renderer$"):
        egl_device_id(0, EGL_LIST[:1])


def test_a_worker_opens_its_context_on_its_gpu(monkeypatch):
    from spm_data.errors import RenderError
    from spm_data.render import pyrender_backend
    from spm_data.render.base import GPU_VARIABLE

    monkeypatch.setattr(pyrender_backend, "_egl_extensions", lambda: EGL_LIST)
    for name in ("EGL_DEVICE_ID", GPU_VARIABLE):  # recorded as they are, so the test leaves them so
        monkeypatch.setenv(name, "")
        monkeypatch.delenv(name)
    monkeypatch.setenv(GPU_VARIABLE, "1")
    pyrender_backend._choose_device()
    assert pyrender_backend.os.environ["EGL_DEVICE_ID"] == "2"
    monkeypatch.delenv(GPU_VARIABLE)
    monkeypatch.setenv("EGL_DEVICE_ID", "0")       # the user's own choice stands when none was assigned
    pyrender_backend._choose_device()
    assert pyrender_backend.os.environ["EGL_DEVICE_ID"] == "0"
    monkeypatch.delenv("EGL_DEVICE_ID")
    pyrender_backend._choose_device()
    assert pyrender_backend.os.environ["EGL_DEVICE_ID"] == "1"
    monkeypatch.setenv(GPU_VARIABLE, "7")
    with pytest.raises(RenderError, match="there is no GPU 7 here"):
        pyrender_backend._choose_device()


def test_this_machines_gpus_the_gl_renderer_readback_time_and_one_blas_thread(renderer):
    from threadpoolctl import threadpool_info

    from spm_data.render.pyrender_backend import visible_gpus

    r, _ = renderer
    name = r.gl_renderer()
    gpus, lister = visible_gpus()
    assert name and lister == "pyrender's EGL"
    if "llvmpipe" in name:   # Mesa's software renderer: no GPU to choose
        assert gpus == ()
    r.set_mesh(procedural_mesh("cup", 0))
    R, t = camera_path(CameraGrid()).poses(slice(3, 4))
    before = r.readback_seconds
    r.render(R[0], t[0])
    assert r.readback_seconds > before
    assert {lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"} == {1}
