import numpy as np
import pytest

from spm_data.errors import ShardError, SpecError
from spm_data.pipelines.render_jobs import load_run_specs, plan_shards, render_dataset
from spm_data.io.files import file_sha256
from spm_data.io.shards import list_shards, read_attrs, read_manifest, read_shard
from spm_data.jobs.executor import LocalExecutor

IMAGE_KEYS = ("rgb", "depth", "mask", "pose", "R", "t", "K", "azimuth", "elevation", "distance", "instance_id")


def arrays_of(folder):
    return {p.name: read_shard(p, IMAGE_KEYS) for p in list_shards(folder)}


def assert_same_arrays(a, b):
    assert a.keys() == b.keys()
    for name in a:
        for key in IMAGE_KEYS:
            np.testing.assert_array_equal(a[name][key], b[name][key], err_msg=f"{name}:{key}")


def test_plan_splits_frames_into_fixed_size_shards(small_specs_dir):
    spec = load_run_specs(["cup"], specs_dir=small_specs_dir)[0]
    jobs = plan_shards(spec, "out")
    assert [j.frames for j in jobs] == [8, 8, 8, 8, 4]  # 2 instances x 18 views
    assert [j.name for j in jobs][:2] == ["cup-00000.h5", "cup-00001.h5"]
    limited = plan_shards(spec, "out", limit=10)
    assert sum(j.frames for j in limited) == 10
    assert set(np.concatenate([j.instances for j in limited])) == {0, 1}  # spread over instances


def test_render_writes_labelled_shards_and_a_manifest(small_specs_dir, tmp_path):
    specs = load_run_specs(all_classes=True, specs_dir=small_specs_dir)
    summary = render_dataset(specs, tmp_path / "out", limit=12)
    assert len(summary.done) == 4 and summary.frames == 24 and not summary.failed
    manifest = read_manifest(tmp_path / "out")
    assert manifest["classes"] == {"box": 12, "cup": 12}
    assert [e["file"] for e in manifest["shards"]] == ["box-00000.h5", "box-00001.h5", "cup-00000.h5",
                                                        "cup-00001.h5"]
    for entry in manifest["shards"]:
        assert entry["sha256"] == file_sha256(tmp_path / "out" / entry["file"])
    data = read_shard(tmp_path / "out" / "cup-00000.h5")
    assert data["rgb"].shape == (8, 64, 64, 3) and data["mask"].max() == 1
    assert set(data["source"]) == {"synthetic"} and set(data["class_name"]) == {"cup"}
    # Labels agree with the path parameters (poses.py's documented reading).
    np.testing.assert_allclose(data["pose"][:, 5], data["distance"], atol=1e-12)
    attrs = read_attrs(tmp_path / "out" / "cup-00000.h5")
    assert attrs["renderer"] == "pyrender" and attrs["seed"] == 3 and 'class = "cup"' in attrs["spec"]
    assert not list((tmp_path / "out").glob(".*.partial")) and not (tmp_path / "out" / ".spm.lock").exists()


def test_same_seed_same_arrays_other_seed_other_arrays(small_specs_dir, tmp_path):
    a = render_dataset(load_run_specs(["cup"], specs_dir=small_specs_dir), tmp_path / "a", limit=8)
    b = render_dataset(load_run_specs(["cup"], specs_dir=small_specs_dir), tmp_path / "b", limit=8)
    c = render_dataset(load_run_specs(["cup"], specs_dir=small_specs_dir, seed=99), tmp_path / "c", limit=8)
    assert a.frames == b.frames == c.frames == 8
    assert_same_arrays(arrays_of(tmp_path / "a"), arrays_of(tmp_path / "b"))
    assert not np.array_equal(arrays_of(tmp_path / "a")["cup-00000.h5"]["rgb"],
                              arrays_of(tmp_path / "c")["cup-00000.h5"]["rgb"])


def test_two_workers_give_the_same_arrays_as_one(small_specs_dir, tmp_path):
    specs = load_run_specs(["cup"], specs_dir=small_specs_dir)
    render_dataset(specs, tmp_path / "one", limit=20)
    summary = render_dataset(specs, tmp_path / "two", limit=20, executor=LocalExecutor(workers=2))
    assert len(summary.done) == 3 and not summary.failed
    assert_same_arrays(arrays_of(tmp_path / "one"), arrays_of(tmp_path / "two"))


def test_rerun_resumes_and_a_changed_plan_is_refused(small_specs_dir, tmp_path):
    specs = load_run_specs(["cup"], specs_dir=small_specs_dir)
    out = tmp_path / "out"
    render_dataset(specs, out, limit=16)
    (out / "cup-00001.h5").unlink()  # as if the run had died before this shard
    again = render_dataset(specs, out, limit=16)
    assert again.skipped == ["cup-00000.h5"] and again.done == ["cup-00001.h5"]
    assert read_manifest(out)["frames"] == 16
    with pytest.raises(ShardError, match="made with seed = 3, not seed = 5"):
        render_dataset(load_run_specs(["cup"], specs_dir=small_specs_dir, seed=5), out, limit=16)


def test_a_refusal_names_the_key_that_differs_and_both_values(small_specs_dir, tmp_path):
    """A spec key, the seed, --limit: the first that differs, old value then new, in one line."""
    out = tmp_path / "out"
    render_dataset(load_run_specs(["cup"], specs_dir=small_specs_dir), out, limit=8)
    shard, spec = out / "cup-00000.h5", small_specs_dir / "cup.toml"
    text = spec.read_text()

    def refusal(limit=8, seed=None, edit=("", "")):
        spec.write_text(text.replace(*edit))
        try:
            with pytest.raises(ShardError) as e:
                render_dataset(load_run_specs(["cup"], specs_dir=small_specs_dir, seed=seed), out, limit=limit)
        finally:
            spec.write_text(text)
        return str(e.value)

    tail = f"; write into a new --out folder or delete {out}"
    assert refusal(edit=("azimuth = [0, 25, 5]", "azimuth = [0, 20, 10]")) == (
        f"{shard} was made with camera.azimuth = [0, 25, 5], not camera.azimuth = [0, 20, 10]{tail}")
    assert refusal(edit=("width = 64",
                         "width = 32")) == f"{shard} was made with image.width = 64, not image.width = 32{tail}"
    assert refusal(seed=4) == f"{shard} was made with seed = 3, not seed = 4{tail}"
    assert refusal(limit=6) == f"{shard} was made with --limit 8, not --limit 6{tail}"
    assert render_dataset(load_run_specs(["cup"], specs_dir=small_specs_dir), out, limit=8).skipped == [shard.name]


def test_output_path_that_is_a_file_is_refused(small_specs_dir, tmp_path):
    (tmp_path / "out").write_text("x")
    with pytest.raises(ShardError, match="is a file"):
        render_dataset(load_run_specs(["cup"], specs_dir=small_specs_dir), tmp_path / "out", limit=2)


def test_unknown_class_and_nothing_to_render(small_specs_dir):
    with pytest.raises(SpecError, match="no spec for class 'teapot'.*available: box, cup"):
        load_run_specs(["teapot"], specs_dir=small_specs_dir)
    with pytest.raises(SpecError, match="nothing to render"):
        load_run_specs(specs_dir=small_specs_dir)


def test_user_mesh_spec_renders(tmp_path):
    import trimesh

    (tmp_path / "meshes").mkdir()
    trimesh.creation.torus(1.0, 0.3).export(tmp_path / "meshes" / "ring.obj")
    trimesh.creation.cone(0.5, 1.0).export(tmp_path / "meshes" / "cone.stl")
    spec_file = tmp_path / "mine.toml"
    spec_file.write_text('class = "mine"\n[mesh]\nsource = "files"\nfiles = ["meshes/*.obj", "meshes/*.stl"]\n'
                         '[camera]\nazimuth = [0, 10, 5]\nelevation = 30\n[image]\nwidth = 48\nheight = 48\n')
    summary = render_dataset(load_run_specs(spec_files=[spec_file]), tmp_path / "out")
    assert summary.frames == 6
    data = read_shard(tmp_path / "out" / "mine-00000.h5", ["instance_name", "mask"])
    assert list(data["instance_name"]) == ["ring"] * 3 + ["cone"] * 3
    assert data["mask"].sum(axis=(1, 2)).min() > 50


@pytest.mark.parametrize("kind", ["color", "images"])
def test_backgrounds_fill_everything_but_the_object(tmp_path, kind):
    import cv2

    (tmp_path / "bg").mkdir()
    for i, colour in enumerate([(0, 0, 255), (0, 255, 0)]):  # BGR on disk: red and green images
        cv2.imwrite(str(tmp_path / "bg" / f"{i}.png"), np.full((90, 120, 3), colour, np.uint8))
    spec_file = tmp_path / "cup.toml"
    spec_file.write_text('class = "cup"\n[camera]\nazimuth = [0, 30, 5]\nelevation = 0\n[image]\nwidth = 48\n'
                         f'height = 48\n[background]\nkind = "{kind}"\ncolor = [0.2, 0.4, 0.6]\nfolder = "bg"\n'
                         '[render]\nrenderer = "pyrender"\n')
    render_dataset(load_run_specs(spec_files=[spec_file]), tmp_path / "out")
    data = read_shard(tmp_path / "out" / "cup-00000.h5", ["rgb", "mask"])
    outside = data["mask"] == 0
    pixels = data["rgb"][outside]
    if kind == "color":
        assert np.all(pixels == np.round(np.array([0.2, 0.4, 0.6]) * 255).astype(np.uint8))
    else:
        per_frame = [data["rgb"][i][outside[i]] for i in range(len(data["rgb"]))]
        firsts = {tuple(p[0]) for p in per_frame}
        assert firsts <= {(255, 0, 0), (0, 255, 0)} and len(firsts) == 2  # both images used, seeded per frame
        assert all(np.all(p == p[0]) for p in per_frame)
    assert data["rgb"][~outside].mean() > 5  # the object is drawn over it


def test_a_spec_whose_meshes_are_missing_writes_nothing(tmp_path):
    spec_file = tmp_path / "mine.toml"
    spec_file.write_text('class = "mine"\n[mesh]\nsource = "files"\nfiles = ["meshes/*.obj"]\n')
    with pytest.raises(SpecError, match="matches no file"):
        render_dataset(load_run_specs(spec_files=[spec_file]), tmp_path / "out")
    assert not (tmp_path / "out").exists()


# --------------------------------------------------------------------------- bounded memory

FINE_SPEC = """class = "cup"
[mesh]
instances = 4
[camera]
azimuth = [0, 359.99, 0.01]
elevation = [0, 60, 0.01]
[render]
renderer = "pyrender"
"""


@pytest.mark.parametrize("total, limit", [(2, 1), (10, 1), (36, 10), (36, 35), (37, 2), (1000, 7), (936 * 4, 100),
                                          (10**9 + 7, 3), (864_144_000, 4), (864_144_000, 1000), (2**40, 999),
                                          (123_457, 123_456)])
def test_limit_picks_are_the_old_linspace_picks(total, limit):
    from spm_data.pipelines.render_jobs import limit_picks

    if total <= 10**7:
        old = np.unique(np.round(np.linspace(0, total - 1, limit)).astype(np.int64))
    else:  # the same computation as linspace's, only on the picked positions
        old = np.round(np.arange(limit, dtype=np.float64) * (np.float64(total - 1) / max(limit - 1, 1)))
        old[-1] = total - 1 if limit > 1 else 0
        old = np.unique(old.astype(np.int64))
    picks = limit_picks(total, limit)
    assert picks.dtype == np.int64 and picks.tobytes() == old.tobytes()
    assert picks[0] == 0 and (limit == 1 or picks[-1] == total - 1)


def test_plans_are_the_old_plans(small_specs_dir):
    import pickle

    spec = load_run_specs(["cup"], specs_dir=small_specs_dir)[0]
    n_path, n_inst = 18, 2
    instances = np.repeat(np.arange(n_inst, dtype=np.int64), n_path)
    path_idx = np.tile(np.arange(n_path, dtype=np.int64), n_inst)
    for limit in (None, 1, 5, 10, 35, 36, 100):
        keep = np.arange(len(instances))
        if limit is not None and limit < len(instances):
            keep = np.unique(np.round(np.linspace(0, len(instances) - 1, limit)).astype(np.int64))
        jobs = plan_shards(spec, "out", limit)
        assert sum(j.frames for j in jobs) == len(keep)
        np.testing.assert_array_equal(np.concatenate([j.instances for j in jobs]), instances[keep])
        np.testing.assert_array_equal(np.concatenate([j.path_indices for j in jobs]), path_idx[keep])
        again = pickle.loads(pickle.dumps(jobs[-1]))  # jobs travel to worker processes
        np.testing.assert_array_equal(again.path_indices, jobs[-1].path_indices)
        assert again.frames == jobs[-1].frames and again.plan_key == jobs[-1].plan_key
    assert plan_shards(spec, "out")[1].frame_range == (8, 16, 18)  # a range, no per-frame arrays


def test_a_limit_on_a_fine_grid_plans_without_the_full_frame_list(tmp_path):
    import tracemalloc

    from spm_data.core.paths import camera_path

    (tmp_path / "cup.toml").write_text(FINE_SPEC)
    tracemalloc.start()
    try:
        spec = load_run_specs(spec_files=[tmp_path / "cup.toml"])[0]
        jobs = plan_shards(spec, tmp_path / "out", limit=4)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 50 * 2**20  # the old plan held ~14 GB of index arrays for 864 million frames
    n_path = 36000 * 6001
    assert len(camera_path(spec.camera)) == n_path
    total = 4 * n_path
    (job,) = jobs
    picks = np.round(np.arange(4) * ((total - 1) / 3)).astype(np.int64)
    picks[-1] = total - 1
    np.testing.assert_array_equal(job.instances, picks // n_path)
    np.testing.assert_array_equal(job.path_indices, picks % n_path)


def test_an_absurd_plan_is_refused_in_one_line(tmp_path):
    (tmp_path / "cup.toml").write_text(FINE_SPEC.replace("0.01]", "0.0001]"))
    spec = load_run_specs(spec_files=[tmp_path / "cup.toml"])[0]
    with pytest.raises(SpecError, match=r"^cup: 4 instances x 2,159,944,199,901 camera views = 8,639,776,799,604 "
                                        r"frames, more than 2\*\*40 \(1,099,511,627,776\); use coarser camera "
                                        r"steps or fewer instances$"):
        plan_shards(spec, tmp_path / "out", limit=4)


def test_a_streamed_shard_is_what_write_shard_writes(small_specs_dir, tmp_path, monkeypatch):
    from spm_data.pipelines import render_jobs
    from spm_data.io.shards import write_shard

    def rewrite(path, to):
        """``path``'s fields and attributes written again by write_shard in one piece."""
        attrs = {k: v for k, v in read_attrs(path).items() if k not in ("schema_version", "frames", "height", "width")}
        return write_shard(to, read_shard(path), attrs)

    specs = load_run_specs(["cup"], specs_dir=small_specs_dir)
    assert render_jobs.block_frames(64, 64) >= 8  # one block per shard of this spec
    render_dataset(specs, tmp_path / "one", limit=12)
    for name in ("cup-00000.h5", "cup-00001.h5"):
        shard = tmp_path / "one" / name
        assert file_sha256(rewrite(shard, tmp_path / f"again-{name}")) == file_sha256(shard)
    monkeypatch.setattr(render_jobs, "BLOCK_BYTES", 3 * 64 * 64 * 8)  # blocks of 3 frames: 8 = 3 + 3 + 2
    assert render_jobs.block_frames(64, 64) == 3
    render_dataset(specs, tmp_path / "three", limit=12)
    for name in ("cup-00000.h5", "cup-00001.h5"):
        streamed, whole = read_shard(tmp_path / "three" / name), read_shard(tmp_path / "one" / name)
        again = read_shard(rewrite(tmp_path / "three" / name, tmp_path / f"whole-{name}"))
        assert streamed.keys() == whole.keys() == again.keys()
        for key in whole:
            assert streamed[key].dtype == whole[key].dtype, key
            np.testing.assert_array_equal(streamed[key], whole[key], err_msg=key)
            np.testing.assert_array_equal(again[key], whole[key], err_msg=key)
        assert read_attrs(tmp_path / "three" / name) == read_attrs(tmp_path / "one" / name)


SAMPLED_SPEC = """
class = "cup"
seed = 4
[mesh]
instances = 2
[camera]
sampler = "so3"
views = 9
distance_range = [0.6, 0.8]
[image]
width = 48
height = 48
[render]
renderer = "pyrender"
frames_per_shard = 6
"""


def test_sampled_views_render_the_same_with_workers_and_on_resume(tmp_path):
    from spm_data.core.paths import camera_path

    (tmp_path / "cup.toml").write_text(SAMPLED_SPEC)
    specs = load_run_specs(spec_files=[tmp_path / "cup.toml"])
    one = render_dataset(specs, tmp_path / "one")
    assert one.frames == 18 and len(one.done) == 3          # 2 instances x 9 views, 6 a shard
    render_dataset(specs, tmp_path / "two", executor=LocalExecutor(workers=2))
    assert_same_arrays(arrays_of(tmp_path / "one"), arrays_of(tmp_path / "two"))
    before = file_sha256(tmp_path / "one" / "cup-00001.h5")
    (tmp_path / "one" / "cup-00001.h5").unlink()
    again = render_dataset(specs, tmp_path / "one")
    assert again.done == ["cup-00001.h5"] and file_sha256(tmp_path / "one" / "cup-00001.h5") == before
    # The shards carry the sampled views: frame g is instance g // 9 at view g % 9.
    got = {k: np.concatenate([read_shard(p, [k])[k] for p in list_shards(tmp_path / "one")])
           for k in ("azimuth", "roll", "path_index", "instance_id")}
    views = camera_path(specs[0].camera, specs[0].seed).at(got["path_index"])
    np.testing.assert_array_equal(got["azimuth"], views.azimuth)
    np.testing.assert_array_equal(got["roll"], views.roll)
    assert list(got["path_index"]) == list(range(9)) * 2 and list(got["instance_id"]) == [0] * 9 + [1] * 9
    assert np.ptp(got["roll"]) > 90   # so3: the camera rolls


# --------------------------------------------------------------------------- the frame pipeline

CLUTTERED = """class = "clutter"
seed = 2
[mesh]
generator = "cup"
instances = 2
[camera]
sampler = "sphere"
views = 5
distance_range = [0.6, 0.8]
[randomize]
lights = [1, 3]
base_color = [0.8, 1.2]
backgrounds = ["gradient", "noise", "checker"]
[distractors]
count = 1
visible = [0.4, 0.9]
classes = ["box"]
instances = 1
[outputs]
normals = true
instances = true
coords = true
[image]
width = 40
height = 32
[render]
renderer = "pyrender"
frames_per_shard = 7
"""


class SerialPipeline:
    """The serial path, for comparison: each frame finished (composited, its outputs made) on
    the renderer's thread as it is put, a block's frames stored by write_images (the call
    write_shard makes) at the block's end: what render_shard did before its pipeline."""

    def __init__(self, writer, block, threads=2, ahead=0):
        self.writer, self.block, self.seconds = writer, block, {"composite": 0.0, "compress": 0.0, "write": 0.0}
        self.frames, self.labels, self.start = [], [], 0

    def put(self, task):
        images, labels = task()
        self.frames.append({f: self.writer.check_frame(f, images[f]) for f in self.writer.images})
        self.labels.append(labels)
        if len(self.frames) == self.block or self.start + len(self.frames) == self.writer.frames:
            self.writer.write_images(self.start,
                                     {f: np.stack([fr[f] for fr in self.frames]) for f in self.writer.images})
            self.start, self.frames = self.start + len(self.frames), []

    def close(self):
        return self.labels

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


@pytest.mark.parametrize("block_bytes", [None, 3 * 40 * 32 * 64])  # one block a shard; blocks of 3 frames
def test_the_pipelined_shard_is_the_serial_paths_bytes(tmp_path, monkeypatch, block_bytes):
    """Compositing (random backgrounds), the opt-in outputs, compression and storing run on
    the pipeline's threads: every shard is byte for byte what the serial path writes."""
    from spm_data.pipelines import render_jobs

    (tmp_path / "clutter.toml").write_text(CLUTTERED)
    specs = load_run_specs(spec_files=[tmp_path / "clutter.toml"])
    if block_bytes:
        monkeypatch.setattr(render_jobs, "BLOCK_BYTES", block_bytes)
    piped = render_dataset(specs, tmp_path / "piped")
    monkeypatch.setattr(render_jobs, "FramePipeline", SerialPipeline)
    serial = render_dataset(specs, tmp_path / "serial")
    assert piped.done == serial.done == ["clutter-00000.h5", "clutter-00001.h5"] and piped.frames == 10
    for name in piped.done:
        assert file_sha256(tmp_path / "piped" / name) == file_sha256(tmp_path / "serial" / name), name
    seconds = piped.results["clutter-00000.h5"]["seconds"]
    assert set(seconds) == {"render", "readback", "composite", "compress", "write"}
    assert all(v > 0 for v in seconds.values()) and seconds["readback"] < seconds["render"] + seconds["readback"]


def pipeline_writer(tmp_path, n=4):
    from spm_data.io.shards import IMAGE_FIELDS, ShardWriter
    from tests.helpers import make_arrays

    arrays = make_arrays(n=n, seed=1)
    images = [f for f in IMAGE_FIELDS if f in arrays]
    return arrays, images, ShardWriter(tmp_path / "a.h5", frames=n, height=8, width=10, images=images)


def test_the_pipeline_holds_at_most_ahead_frames_and_gives_labels_in_order(tmp_path):
    import threading

    from spm_data.pipelines.render_frames import FramePipeline

    arrays, images, shard = pipeline_writer(tmp_path)
    go, started = threading.Event(), []

    def frame(i):
        started.append(i)
        go.wait()  # held until the test has looked at the pipeline
        return {f: arrays[f][i] for f in images}, {"i": i}

    with shard as writer, FramePipeline(writer, block=4, threads=2, ahead=2) as pipeline:
        pipeline.put(lambda: frame(0))
        pipeline.put(lambda: frame(1))
        assert not pipeline._room.acquire(blocking=False)  # two frames in hand: a third put would wait
        go.set()
        pipeline.put(lambda: frame(2))
        pipeline.put(lambda: frame(3))
        assert [labels["i"] for labels in pipeline.close()] == [0, 1, 2, 3]
        assert not pipeline._thread.is_alive()


def test_a_failing_frame_is_raised_on_the_renderers_thread_and_nothing_is_left(tmp_path):
    from spm_data.pipelines.render_frames import FramePipeline
    from spm_data.errors import RenderError

    arrays, images, shard = pipeline_writer(tmp_path)

    def bad():
        raise RenderError("frame 1 failed")

    with pytest.raises(RenderError, match="^frame 1 failed$"):
        with shard as writer, FramePipeline(writer, block=4, threads=2) as pipeline:
            pipeline.put(lambda: ({f: arrays[f][0] for f in images}, {}))
            pipeline.put(bad)
            for i in (2, 3):
                pipeline.put(lambda i=i: ({f: arrays[f][i] for f in images}, {}))
            pipeline.close()
    with pytest.raises(ShardError, match=r"^shard field 'rgb': expected a frame of \(8, 10, 3\), got \(8, 9, 3\)$"):
        with pipeline_writer(tmp_path)[2] as writer, FramePipeline(writer, block=2, threads=2) as pipeline:
            for i in range(4):
                pipeline.put(lambda i=i: ({**{f: arrays[f][i] for f in images}, "rgb": arrays["rgb"][i][:, :9]}, {}))
            pipeline.close()
    with pytest.raises(ShardError, match=r"^a\.h5: 3 of 4 frames given; not written$"):
        with pipeline_writer(tmp_path)[2] as writer, FramePipeline(writer, block=4, threads=2) as pipeline:
            for i in range(3):
                pipeline.put(lambda i=i: ({f: arrays[f][i] for f in images}, {}))
            pipeline.close()
    assert list(tmp_path.iterdir()) == []


def test_a_failed_store_stops_the_render_and_an_early_exit_stops_the_threads(tmp_path, monkeypatch):
    from spm_data.pipelines.render_frames import FramePipeline

    arrays, images, shard = pipeline_writer(tmp_path)

    def full(field, index, chunk):
        raise ShardError("could not write shard a.h5: No space left on device")

    with pytest.raises(ShardError, match="No space left on device"):
        with shard as writer, FramePipeline(writer, block=4, threads=2) as pipeline:
            monkeypatch.setattr(writer, "store_chunk", full)
            for i in range(4):
                pipeline.put(lambda i=i: ({f: arrays[f][i] for f in images}, {}))
            pipeline.close()
    with pytest.raises(KeyboardInterrupt):
        with pipeline_writer(tmp_path)[2] as writer, FramePipeline(writer, block=4, threads=2) as pipeline:
            pipeline.put(lambda: ({f: arrays[f][0] for f in images}, {}))
            raise KeyboardInterrupt  # Ctrl-C while rendering frame 1
    assert not pipeline._thread.is_alive() and list(tmp_path.iterdir()) == []


def test_a_workers_pipeline_threads_are_its_share_of_the_cores(monkeypatch):
    from spm_data.pipelines.render_frames import pipeline_threads

    for cores, threads in (("1", 2), ("8", 8), ("64", 16)):
        monkeypatch.setenv("SPM_WORKER_CORES", cores)
        assert pipeline_threads() == threads
    monkeypatch.delenv("SPM_WORKER_CORES")
    import os

    assert pipeline_threads() == max(2, min(16, len(os.sched_getaffinity(0))))
