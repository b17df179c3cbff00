"""The Blender backend: same geometry as pyrender, recorded settings, crash isolation."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh

from spm_data.core.mesh_files import load_mesh_file
from spm_data.core.shapes import procedural_mesh
from spm_data.core.paths import AngleRange, CameraGrid, camera_path
from spm_data.render import make_renderer
from spm_data.pipelines.render_jobs import load_run_specs, render_dataset
from spm_data.io.shards import list_shards, read_attrs, read_manifest, read_shard
from spm_data.core.specs import parse_spec

pytestmark = pytest.mark.slow  # Blender renders (Cycles and Workbench)



def user_mesh(tmp_path_factory):
    folder = tmp_path_factory.mktemp("mesh")
    knot = trimesh.creation.torus(1.0, 0.35)
    knot.apply_transform(trimesh.transformations.rotation_matrix(0.6, [1, 1, 0]))
    parts = trimesh.util.concatenate([knot, trimesh.creation.box((0.6, 0.6, 2.2))])
    parts.export(folder / "user.obj")
    return load_mesh_file(folder / "user.obj", size=0.25)


@pytest.mark.parametrize("engine", ["cycles", "workbench"])
def test_blender_and_pyrender_agree_on_mask_and_depth(engine, tmp_path_factory):
    spec = parse_spec(f'class = "cup"\n[render.blender]\nengine = "{engine}"\nsamples = 4')
    blender, gl = make_renderer(spec, "blender"), make_renderer(spec, "pyrender")
    path = camera_path(CameraGrid(azimuth=AngleRange(0, 315, 45), elevation=AngleRange(0, 60, 30),
                                  distances=(0.6, 0.8), look_at=(0.01, 0.0, -0.01)))
    meshes = [procedural_mesh("cup", 2), procedural_mesh("motorcycle", 0), user_mesh(tmp_path_factory)]
    frames = 0
    for mesh in meshes:
        blender.set_mesh(mesh)
        gl.set_mesh(mesh)
        for i in range(0, len(path), 4):
            R, t = path.poses(slice(i, i + 1))
            a, b = gl.render(R[0], t[0]), blender.render(R[0], t[0])
            assert b["rgb"].shape == (128, 128, 3) and b["rgb"].dtype == np.uint8
            assert b["depth"].dtype == np.float32 and b["mask"].dtype == np.uint8
            ma, mb = a["mask"] > 0, b["mask"] > 0
            iou = (ma & mb).sum() / (ma | mb).sum()
            assert iou >= 0.98, (mesh.name, i, iou)
            both = ma & mb
            diff = np.median(np.abs(a["depth"][both] - b["depth"][both]))
            assert diff < 0.01 * path.distance[i], (mesh.name, i, diff)
            assert b["rgb"][mb].mean() > 5  # a lit object
            # Black film: colour off the silhouette only at its edge (sub-pixel jitter).
            import cv2

            near = cv2.dilate(b["mask"], np.ones((3, 3), np.uint8)) > 0
            assert b["rgb"][~near].max() == 0
            frames += 1
    blender.close()
    assert frames == 18


def test_cycles_border_and_kept_scene_give_the_frames_of_a_plain_full_render():
    """render() traces only a border around the object and keeps Cycles' scene between
    frames (rebuilt at each set_mesh): every array is the one a plain full-frame render of a
    freshly built scene gives, over mesh switches (a new texture may take the old one's address)."""
    import bpy
    import mathutils

    from spm_data.core.poses import cv_to_gl_camera_to_world

    spec = parse_spec('class = "cup"\n[image]\nwidth = 64\nheight = 48\n[render.blender]\nsamples = 4')
    path = camera_path(CameraGrid(azimuth=AngleRange(0, 300, 60), elevation=AngleRange(0, 60, 60),
                                  distances=(0.6, 0.8), look_at=(0.02, 0.0, -0.01)))
    meshes = [procedural_mesh("cup", 0), procedural_mesh("cup", 1), procedural_mesh("motorcycle", 0),
              procedural_mesh("cup", 0)]
    views = range(0, len(path), 3)
    ours = []
    with make_renderer(spec, "blender") as renderer:
        for mesh in meshes:
            renderer.set_mesh(mesh)
            for i in views:
                R, t = path.poses(slice(i, i + 1))
                ours.append(renderer.render(R[0], t[0]))
                assert bpy.context.scene.render.use_border  # the object is in view: a border
        assert bpy.context.scene.render.use_persistent_data
    plain = []
    for mesh in meshes:
        with make_renderer(spec, "blender") as fresh:
            fresh.set_mesh(mesh)
            bpy.context.scene.render.use_persistent_data = False
            for i in views:
                R, t = path.poses(slice(i, i + 1))
                fresh._camera.matrix_world = mathutils.Matrix(cv_to_gl_camera_to_world(R[0], t[0]).tolist())
                bpy.ops.render.render(write_still=True)
                plain.append(fresh._read_exr())
    assert len(ours) == len(plain) == 4 * len(views)
    for k, (a, b) in enumerate(zip(ours, plain)):
        for name in ("rgb", "alpha", "depth", "mask"):
            np.testing.assert_array_equal(a[name], b[name], err_msg=f"frame {k}, {name}")
        assert b["mask"].any()


def test_an_opaque_film_renders_the_full_frame():
    """Without a transparent film the background is the world's colour, not 0: no border."""
    import bpy

    spec = parse_spec('class = "cup"\n[image]\nwidth = 32\nheight = 32\n[render.blender]\nsamples = 1\n'
                      'film_transparent = false')
    path = camera_path(CameraGrid(azimuth=AngleRange(0, 0, 5), elevation=AngleRange(30, 30, 5), distances=(0.8,)))
    R, t = path.poses(slice(0, 1))
    with make_renderer(spec, "blender") as renderer:
        renderer.set_mesh(procedural_mesh("cup", 0))
        out = renderer.render(R[0], t[0])
        assert not bpy.context.scene.render.use_border
    assert out["rgb"][0, 0].min() > 0 and out["alpha"][0, 0] == 1.0  # a corner: the world, opaque


def test_blender_shards_record_engine_settings(tmp_path):
    spec_file = tmp_path / "cup.toml"
    spec_file.write_text('class = "cup"\n[camera]\nazimuth = [0, 10, 5]\nelevation = 0\n[image]\nwidth = 32\n'
                         'height = 32\n[render.blender]\nsamples = 2\n')
    summary = render_dataset(load_run_specs(spec_files=[spec_file]), tmp_path / "out")
    assert summary.frames == 12 and not summary.failed
    attrs = read_attrs(tmp_path / "out" / "cup-00000.h5")
    assert attrs["renderer"] == "blender" and attrs["renderer_version"].startswith("Blender 5.0")
    assert '"engine": "cycles"' in attrs["renderer_settings"] and '"samples": 2' in attrs["renderer_settings"]


def _workers_of(pid):
    """pids of multiprocessing workers whose parent is ``pid``."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            cmdline = (entry / "cmdline").read_bytes().decode(errors="replace")
        except OSError:
            continue
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        if ppid == pid and "spawn_main" in cmdline:
            found.append(int(entry.name))
    return found


def test_a_blender_worker_killed_mid_shard_loses_nothing(tmp_path):
    spec_file = tmp_path / "cup.toml"
    spec_file.write_text('class = "cup"\n[mesh]\ninstances = 1\n[camera]\nazimuth = [0, 355, 5]\nelevation = 0\n'
                         '[image]\nwidth = 48\nheight = 48\n[render]\nframes_per_shard = 12\n'
                         '[render.blender]\nsamples = 2\n')
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-c", "import cli; cli.data_cli()", "render", "--spec", str(spec_file),
                             "--out", str(out), "--workers", "2"], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    killed = None
    deadline = time.time() + 120
    while time.time() < deadline and killed is None:
        workers = _workers_of(proc.pid)
        # Kill once shards are being written, i.e. mid-run and (very likely) mid-shard.
        if len(workers) == 2 and out.is_dir() and list(out.glob("*.h5")):
            killed = workers[0]
            os.kill(killed, signal.SIGKILL)
        time.sleep(0.05)
    output, _ = proc.communicate(timeout=300)
    assert killed is not None, output
    assert proc.returncode == 0, output
    assert "0 failed" in output
    files = [p.name for p in list_shards(out)]
    assert files == [f"cup-{i:05d}.h5" for i in range(6)]
    manifest = read_manifest(out)
    assert [e["file"] for e in manifest["shards"]] == files and manifest["frames"] == 72
    for f in files:
        data = read_shard(out / f, ["mask", "azimuth"])
        assert data["mask"].shape == (12, 48, 48) and data["mask"].sum(axis=(1, 2)).min() > 0
    assert not list(out.glob(".*.partial"))


def test_device_auto_falls_back_to_the_cpu_and_gpu_without_one_is_one_line(tmp_path):
    from spm_data.errors import RenderError

    base = ('class = "cup"\n[image]\nwidth = 32\nheight = 32\n[render]\nrenderer = "blender"\n'
            '[render.blender]\nsamples = 1\ndevice = "{}"\n')
    renderer = make_renderer(parse_spec(base.format("auto")))
    try:
        renderer.set_mesh(procedural_mesh("cup", 0))
        R, t = camera_path(CameraGrid()).poses([0])
        assert renderer.render(R[0], t[0])["mask"].any()
        assert renderer.settings()["device"] == "CPU"     # no GPU on this machine: the CPU, recorded
    finally:
        renderer.close()
    with pytest.raises(RenderError, match=r'device = "gpu": Blender finds no GPU here \(tried OPTIX, CUDA'):
        make_renderer(parse_spec(base.format("gpu")))
    # A run of several shards: one error line, no summary of a folder that was never made.
    from click.testing import CliRunner

    from cli import data_cli

    (tmp_path / "gpu.toml").write_text(base.format("gpu").replace("samples = 1", "samples = 1\n") +
                                       "[camera]\nazimuth = [0, 15, 5]\nelevation = 0\n")
    (tmp_path / "gpu.toml").write_text((tmp_path / "gpu.toml").read_text().replace(
        '[render]\nrenderer = "blender"\n', '[render]\nrenderer = "blender"\nframes_per_shard = 2\n'))
    r = CliRunner().invoke(data_cli, ["render", "--spec", str(tmp_path / "gpu.toml"), "--out", str(tmp_path / "out")])
    assert r.exit_code == 1 and r.output.count("\n") == 1, r.output
    assert r.output.startswith('error: render.blender.device = "gpu": Blender finds no GPU here')
    assert not (tmp_path / "out").exists()


def test_blender_and_pyrender_agree_on_a_randomised_cluttered_spec(tmp_path):
    """Same draws, same distractor poses: visible masks (IoU >= 0.97), normals (median
    angle <= 5 degrees) and each visible fraction within 2% of its draw, in both."""
    from tests.pipelines.test_render_frames import CLUTTERED

    folder = tmp_path / "specs"
    folder.mkdir()
    (folder / "c.toml").write_text(CLUTTERED.format(cls="c") + "[render.blender]\nsamples = 4\n")
    shards = {}
    for name in ("pyrender", "blender"):
        specs = load_run_specs(all_classes=True, specs_dir=folder, renderer=name)
        assert render_dataset(specs, tmp_path / name, limit=8).failed == []
        shards[name] = read_shard(list_shards(tmp_path / name)[0])
    a, b = shards["pyrender"], shards["blender"]
    for key in ("K", "lights", "material", "distractor_t", "visible_target"):
        np.testing.assert_array_equal(a[key], b[key])  # the same draws
    for i in range(8):
        for d in (a, b):
            seen, area = d["visible_mask"][i].sum(), d["mask"][i].sum()
            assert abs(seen / area - d["visible_target"][i]) <= 0.02
        va, vb = a["visible_mask"][i] > 0, b["visible_mask"][i] > 0
        assert (va & vb).sum() / (va | vb).sum() >= 0.97
        both = (a["instances"][i] > 0) & (a["instances"][i] == b["instances"][i])
        cos = np.sum(a["normals"][i][both].astype(np.float32) * b["normals"][i][both].astype(np.float32), axis=1)
        assert np.median(np.degrees(np.arccos(np.clip(cos, -1, 1)))) <= 5.0
    assert b["rgb"][b["instances"] > 0].mean() > 20  # lit


def test_kept_scene_and_border_honour_per_frame_draws_and_distractors():
    """With persistent data and the render border, frames whose lights, material, K and
    distractors change every frame are the frames a fresh full-frame scene renders."""
    from dataclasses import replace

    import bpy

    from spm_data.core.distractors import place_distractors
    from spm_data.core.randomize import frame_draws
    from spm_data.core.specs import load_spec

    # The shipped example (frame 5 swaps a distractor slot's mesh, whose Blender bounding box lags a frame)
    spec = load_spec(Path(__file__).resolve().parents[2] / "examples" / "specs" / "cup-cluttered.toml")
    spec = spec.replace(render=replace(spec.render, renderer="blender",
                                       blender=replace(spec.render.blender, samples=1)))
    mesh = procedural_mesh("cup", 0)
    R, t = camera_path(spec.camera, spec.seed).poses(slice(0, 10))
    frames = []
    for i in range(10):  # distractor slots change mesh between frames (Blender's bounding boxes lag)
        draws = frame_draws(spec, 0, i)
        frames.append((R[i], t[i], draws, place_distractors(spec, mesh, R[i], t[i], draws.K, 0, i).distractors))
    with make_renderer(spec, "blender") as kept:
        kept.set_mesh(mesh)
        ours = [kept.render(*f) for f in frames]
    for k, frame in enumerate(frames):
        with make_renderer(spec, "blender") as fresh:
            fresh.set_mesh(mesh)
            bpy.context.scene.render.use_persistent_data = False
            fresh._set_border = lambda R, t, distractors=(): None  # the full frame
            bpy.context.scene.render.use_border = False
            plain = fresh.render(*frame)
        for name in ("rgb", "depth", "mask", "instances", "normals"):
            np.testing.assert_array_equal(ours[k][name], plain[name], err_msg=f"frame {k}, {name}")
        assert len(np.unique(ours[k]["instances"])) >= 3  # the target and distractors in view
