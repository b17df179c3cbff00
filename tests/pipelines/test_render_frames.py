"""Rendered frames with [randomize], [distractors] and [outputs], through the whole render path."""

import json
import re

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from spm_data.pipelines.occlude_jobs import occlude_dataset
from spm_data.pipelines.render_jobs import load_run_specs, render_dataset
from spm_data.core.instances import load_instance
from spm_data.core.mesh_store import has_mesh
from spm_data.errors import ShardError
from spm_data.io.files import file_sha256
from spm_data.io.shards import list_shards, read_attrs, read_shard
from spm_data.jobs.executor import LocalExecutor

CLUTTERED = """class = "{cls}"
seed = 4
[mesh]
generator = "cup"
instances = 2
[camera]
sampler = "sphere"
views = 12
elevation_range = [0, 50]
roll_range = [-30, 30]
distance_range = [0.6, 0.8]
[randomize]
lights = [1, 3]
light_strength = [1.0, 2.0]
base_color = [0.8, 1.2]
roughness = [0.4, 1.0]
backgrounds = ["gradient", "noise"]
focal = [0.97, 1.03]
principal_point = 2.0
[distractors]
count = 2
visible = [0.3, 0.9]
classes = ["box", "ball"]
instances = 2
[outputs]
normals = true
instances = true
coords = true
[render]
renderer = "pyrender"
frames_per_shard = 8
"""


@pytest.fixture(scope="module")
def cluttered_specs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("specs")
    (folder / "cluttered.toml").write_text(CLUTTERED.format(cls="cluttered"))
    return load_run_specs(all_classes=True, specs_dir=folder)


@pytest.fixture(scope="module")
def cluttered(cluttered_specs, tmp_path_factory):
    """16 frames of the cluttered spec, rendered once for the module. Read-only for tests."""
    out = tmp_path_factory.mktemp("cluttered") / "out"
    render_dataset(cluttered_specs, out, limit=16)
    return out


def test_the_visible_fraction_lands_within_two_percent_of_its_draw(cluttered):
    for path in list_shards(cluttered):
        d = read_shard(path)
        area = d["mask"].reshape(len(d["mask"]), -1).sum(1)
        seen = d["visible_mask"].reshape(len(d["mask"]), -1).sum(1)
        assert np.all(area > 300)
        np.testing.assert_array_less(np.abs(seen / area - d["visible_target"]), 0.02)
        np.testing.assert_allclose(d["occlusion_fraction"], 1 - seen / area, atol=1e-6)
        assert np.all(d["visible_mask"] <= d["mask"])


def test_instances_normals_and_coords_describe_the_frame(cluttered):
    for path in list_shards(cluttered):
        d = read_shard(path)
        ids = d["instances"]
        assert set(np.unique(ids)) >= {0, 1, 2}
        # visible: the amodal mask where the target is drawn, or nothing is (BOP's rule for no depth)
        np.testing.assert_array_equal(d["visible_mask"] > 0, ((ids == 1) | (d["depth"] == 0)) & (d["mask"] > 0))
        n = d["normals"].astype(np.float32)
        np.testing.assert_allclose(np.linalg.norm(n[ids > 0], axis=1), 1.0, atol=2e-3)
        assert not n[ids == 0].any()
        # Normals face the camera where a surface is seen head-on: most point against the view ray (+z).
        assert np.mean(n[ids > 0][:, 2] < 0) > 0.8
        for i in range(0, len(ids), 3):
            coords = d["coords"][i][ids[i] == 1].astype(np.float64)
            mesh = load_instance(_spec(cluttered), int(d["instance_id"][i])).to_trimesh()
            surface = cKDTree(trimesh.sample.sample_surface_even(mesh, 200_000, seed=0)[0])
            distance, _ = surface.query(coords)
            # On the surface: within the samples' spacing (about 1 mm); a wrong frame is centimetres off.
            assert np.median(distance) < 1.5e-3 and np.percentile(distance, 99) < 4e-3
            assert not d["coords"][i][ids[i] != 1].any()


def test_every_pixel_with_depth_has_the_label_of_what_the_depth_shows(tmp_path):
    # Seed 6 at 128 px: a frame of the first 24 is one where Mesa's label pass misses a silhouette pixel the colour
    # pass drew (labels_agreeing_with_depth). Depth, mask and labels must still say the same.
    (tmp_path / "specs").mkdir()
    spec = CLUTTERED.format(cls="c").replace("seed = 4", "seed = 6").replace("normals = true", "normals = false")
    (tmp_path / "specs" / "c.toml").write_text(spec.replace("[render]", "[image]\nwidth = 128\nheight = 128\n[render]"))
    render_dataset(load_run_specs(all_classes=True, specs_dir=tmp_path / "specs"), tmp_path / "out", limit=24)
    for path in list_shards(tmp_path / "out"):
        d = read_shard(path, ["depth", "instances", "visible_mask", "mask"])
        np.testing.assert_array_equal(d["instances"] > 0, d["depth"] > 0)
        visible = ((d["instances"] == 1) | (d["depth"] == 0)) & (d["mask"] > 0)
        np.testing.assert_array_equal(d["visible_mask"] > 0, visible)


def _spec(folder):
    from spm_data.core.specs import parse_spec

    return parse_spec(read_attrs(list_shards(folder)[0])["spec"])


def test_the_shard_records_the_draws_and_the_distractors(cluttered):
    d = read_shard(list_shards(cluttered)[0])
    attrs = read_attrs(list_shards(cluttered)[0])
    assert d["lights"].shape[1:] == (3, 7) and d["material"].shape[1:] == (5,)
    assert np.ptp(d["K"][:, 0, 0]) > 0 and np.ptp(d["K"][:, 0, 2]) > 0  # K jitters per frame
    assert d["distractor_R"].shape[1:] == (2, 3, 3) and np.all(d["distractor_mesh"] >= 0)
    import json

    assert json.loads(attrs["distractor_meshes"]) == ["box-10000", "box-10001", "ball-10000", "ball-10001"]
    assert np.all(d["distractor_t"][:, :, 2] > 0) and np.all(d["distractor_size"] > 0)


def test_the_shard_says_what_was_randomised_and_each_frame_s_background(cluttered):
    import json

    from spm_data.core.randomize import frame_draws
    from spm_data.core.specs import parse_spec

    path = list_shards(cluttered)[0]
    d, attrs = read_shard(path), read_attrs(path)
    settings = json.loads(attrs["renderer_settings"])
    # The drawn ones as their ranges (the spec's fixed 3 lights at 1.6 lit no frame); ambient stays fixed.
    assert settings["lights"] == [1, 3] and type(settings["lights"][0]) is int
    assert settings["strength"] == [1.0, 2.0] and settings["ambient"] == 0.3
    assert settings["randomized"] == ["backgrounds", "base_color", "focal", "light_strength", "lights",
                                      "principal_point", "roughness"]
    spec = parse_spec(attrs["spec"])
    want = [frame_draws(spec, int(i), int(p)).background for i, p in zip(d["instance_id"], d["path_index"])]
    assert [str(b) for b in d["background"]] == want and set(want) == {"gradient", "noise"}


def test_two_workers_and_a_rerun_give_the_same_shards(cluttered_specs, cluttered, tmp_path):
    two = render_dataset(cluttered_specs, tmp_path / "two", limit=16, executor=LocalExecutor(workers=2))
    assert two.failed == []
    for a, b in zip(list_shards(cluttered), list_shards(tmp_path / "two")):
        assert file_sha256(a) == file_sha256(b)
    first = list_shards(tmp_path / "two")[0]
    before = file_sha256(first)
    first.unlink()  # a lost shard is rendered again, to the same bytes
    render_dataset(cluttered_specs, tmp_path / "two", limit=16)
    assert file_sha256(first) == before


def test_occluding_a_shard_that_has_distractors_is_refused(cluttered, tmp_path):
    with pytest.raises(ShardError, match="already occluded \\(it has a visible_mask"):
        occlude_dataset(cluttered, tmp_path / "occ")
    assert not (tmp_path / "occ").exists() or not list((tmp_path / "occ").glob("*.h5"))


def test_merge_keeps_the_distractor_fields(cluttered, tmp_path):
    from spm_data.pipelines.merge import merge_folders

    merge_folders([cluttered], tmp_path / "merged")
    merged = read_shard(list_shards(tmp_path / "merged")[0])
    original = read_shard(list_shards(cluttered)[0])
    np.testing.assert_array_equal(merged["distractor_t"][:8], original["distractor_t"])
    np.testing.assert_array_equal(merged["normals"][:8], original["normals"])
    np.testing.assert_array_equal(merged["distractor_mesh"][:8], original["distractor_mesh"])
    assert read_attrs(list_shards(tmp_path / "merged")[0])["distractor_meshes"] == \
        read_attrs(list_shards(cluttered)[0])["distractor_meshes"]


def test_a_spec_without_lights_renders(tmp_path):
    folder = tmp_path / "specs"
    folder.mkdir()
    (folder / "dark.toml").write_text('class = "cup"\n[camera]\nazimuth = [0, 10, 5]\nelevation = 0\n'
                                      '[randomize]\nlights = [0, 0]\n[render]\nrenderer = "pyrender"\n')
    summary = render_dataset(load_run_specs(all_classes=True, specs_dir=folder), tmp_path / "out")
    assert summary.failed == [] and summary.frames == 3 * 3 * 4 // 3  # 3 views x 4 instances
    assert read_shard(list_shards(tmp_path / "out")[0], ["lights"])["lights"].shape[1:] == (1, 7)


def _frame_pool_names(folder):
    """Per frame of every shard in ``folder``: the pool names its distractor_mesh indices stand for."""
    out = []
    for path in list_shards(folder):
        pool = json.loads(read_attrs(path)["distractor_meshes"])
        out += [[pool[k] if k >= 0 else None for k in row] for row in read_shard(path)["distractor_mesh"]]
    return out


def test_merge_of_datasets_with_different_distractor_pools_makes_one_pool(tmp_path):
    from spm_data.pipelines.merge import merge_folders

    for name, cls in (("a", "box"), ("b", "ball")):
        folder = tmp_path / f"specs_{name}"
        folder.mkdir()
        text = CLUTTERED.format(cls=name).replace('classes = ["box", "ball"]', f'classes = ["{cls}"]')
        (folder / f"{name}.toml").write_text(text)
        render_dataset(load_run_specs(all_classes=True, specs_dir=folder), tmp_path / name, limit=4)
    summary = merge_folders([tmp_path / "a", tmp_path / "b"], tmp_path / "merged")
    assert summary.failed == []
    merged = read_shard(list_shards(tmp_path / "merged")[0])
    assert merged["distractor_R"].shape[:2] == (8, 2) and merged["distractor_mesh"].shape == (8, 2)
    # Each frame's distractors still name the meshes they were drawn from, now in one pool.
    both = _frame_pool_names(tmp_path / "a") + _frame_pool_names(tmp_path / "b")
    assert _frame_pool_names(tmp_path / "merged") == both
    digests = json.loads(read_attrs(list_shards(tmp_path / "merged")[0])["distractor_mesh_digests"])
    assert all(has_mesh(tmp_path / "merged", d) for d in digests if d)


def test_merge_keeps_same_named_meshes_of_other_seeds_apart(tmp_path):
    from spm_data.pipelines.merge import merge_folders

    for name, seed in (("a", 1), ("b", 2)):
        folder = tmp_path / f"specs_{name}"
        folder.mkdir()
        (folder / f"{name}.toml").write_text(CLUTTERED.format(cls=name).replace("seed = 4", f"seed = {seed}"))
        render_dataset(load_run_specs(all_classes=True, specs_dir=folder), tmp_path / name, limit=4)
    merge_folders([tmp_path / "a", tmp_path / "b"], tmp_path / "merged")
    path = list_shards(tmp_path / "merged")[0]
    merged, attrs = read_shard(path), read_attrs(path)
    names, digests = json.loads(attrs["distractor_meshes"]), json.loads(attrs["distractor_mesh_digests"])
    assert merged["distractor_t"].shape[:2] == (8, 2) and len(names) == len(digests)
    used = {int(k) for k in merged["distractor_mesh"][4:].ravel() if k >= 0}   # b's frames
    first = {int(k) for k in merged["distractor_mesh"][:4].ravel() if k >= 0}
    assert not used & first   # same names, other meshes: other pool entries
    assert {digests[k] for k in used}.isdisjoint({digests[k] for k in first})


def test_merge_of_cluttered_and_plain_frames_keeps_the_distractors(tmp_path):
    from spm_data.pipelines.merge import merge_folders
    plain = re.sub(r"\[distractors\]\n(?:[a-z].*\n)*", "", CLUTTERED.format(cls="box"))   # the same frames, uncluttered
    for name, text in (("a", CLUTTERED.format(cls="a")), ("box", plain)):
        folder = tmp_path / f"specs_{name}"
        folder.mkdir()
        (folder / f"{name}.toml").write_text(text)
        render_dataset(load_run_specs(all_classes=True, specs_dir=folder), tmp_path / name, limit=4)
    merge_folders([tmp_path / "a", tmp_path / "box"], tmp_path / "merged")
    merged = read_shard(list_shards(tmp_path / "merged")[0])
    assert merged["distractor_mesh"].shape == (8, 2) and (merged["distractor_mesh"][4:] == -1).all()
    assert _frame_pool_names(tmp_path / "merged")[:4] == _frame_pool_names(tmp_path / "a")
    assert (merged["distractor_size"][4:] == 0).all() and "visible_target" not in merged


def test_merge_of_occluded_and_plain_frames_keeps_what_is_hidden(tmp_path):
    from spm_data.pipelines.merge import merge_folders

    folder = tmp_path / "specs"
    folder.mkdir()
    plain = re.sub(r"\[distractors\]\n(?:[a-z].*\n)*", "", CLUTTERED.format(cls="box"))
    (folder / "box.toml").write_text(plain)
    render_dataset(load_run_specs(all_classes=True, specs_dir=folder), tmp_path / "a", limit=4)
    occlude_dataset(tmp_path / "a", tmp_path / "a_occ", low=0.3, high=0.5)
    merge_folders([tmp_path / "a", tmp_path / "a_occ"], tmp_path / "merged")
    merged = read_shard(list_shards(tmp_path / "merged")[0])
    occluded = read_shard(list_shards(tmp_path / "a_occ")[0])
    assert np.array_equal(merged["visible_mask"][:4], merged["mask"][:4])   # the plain frames: all seen
    assert np.array_equal(merged["visible_mask"][4:], occluded["visible_mask"])
    assert (merged["visible_mask"][4:].sum(axis=(1, 2)) < merged["mask"][4:].sum(axis=(1, 2))).all()


def test_the_pipeline_runs_behind_the_renderer_and_gives_the_switch_interval_back(tmp_path):
    """Its threads at niceness PIPELINE_NICE (their own), the GIL's switch interval SWITCH_SECONDS
    while it runs, and Python's own again after it, also when the render fails."""
    import os
    import sys
    import threading

    from spm_data.pipelines.render_frames import PIPELINE_NICE, SWITCH_SECONDS, FramePipeline
    from tests.pipelines.test_render_jobs import pipeline_writer

    arrays, images, shard = pipeline_writer(tmp_path)
    before, mine = sys.getswitchinterval(), os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    seen = []

    def frame(i):
        seen.append((os.getpriority(os.PRIO_PROCESS, threading.get_native_id()), sys.getswitchinterval()))
        return {f: arrays[f][i] for f in images}, {}

    with shard as writer, FramePipeline(writer, block=4, threads=2) as pipeline:
        for i in range(4):
            pipeline.put(lambda i=i: frame(i))
        pipeline.close()
    assert seen == [(max(mine, PIPELINE_NICE), SWITCH_SECONDS)] * 4
    assert sys.getswitchinterval() == before
    assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == mine   # the renderer's thread as it was
    (tmp_path / "b").mkdir()
    with pytest.raises(RuntimeError), pipeline_writer(tmp_path / "b")[2] as writer, FramePipeline(writer, 4):
        raise RuntimeError("the render failed")
    assert sys.getswitchinterval() == before
