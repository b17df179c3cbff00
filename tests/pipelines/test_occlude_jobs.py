from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from cli import data_cli
from spm_data.pipelines.occlude_jobs import occlude_dataset
from spm_data.errors import ShardError
from spm_data.pipelines.render_jobs import load_run_specs, render_dataset
from spm_data.io.files import file_sha256
from spm_data.io.shards import list_shards, read_attrs, read_manifest, read_shard, write_manifest, write_shard
from spm_data.jobs.executor import LocalExecutor


@pytest.fixture(scope="module")
def rendered(tmp_path_factory, request):
    folder = tmp_path_factory.mktemp("specs")
    (folder / "cup.toml").write_text('class = "cup"\n[mesh]\ninstances = 2\n[camera]\nazimuth = [0, 60, 5]\n'
                                     'elevation = [0, 20, 10]\n[render]\nrenderer = "pyrender"\n'
                                     'frames_per_shard = 40\n')
    out = tmp_path_factory.mktemp("rendered")
    render_dataset(load_run_specs(["cup"], specs_dir=folder), out)
    return out


def hashes(folder):
    """Every file's hash, the mesh store's included."""
    return {str(p.relative_to(folder)): file_sha256(p) for p in sorted(folder.rglob("*")) if p.is_file()}


def test_fractions_lie_in_range_and_input_is_untouched(rendered, tmp_path):
    before = hashes(rendered)
    summary = occlude_dataset(rendered, tmp_path / "occ", low=0.1, high=0.6)
    assert hashes(rendered) == before
    assert summary.frames == 78 and len(summary.done) == 2
    for path in list_shards(tmp_path / "occ"):
        src = read_shard(rendered / path.name)
        d = read_shard(path)
        assert ((d["occlusion_fraction"] >= 0.1) & (d["occlusion_fraction"] <= 0.6)).all()
        np.testing.assert_array_equal(d["mask"], src["mask"])      # full silhouette kept
        np.testing.assert_array_equal(d["depth"], src["depth"])    # depth left as rendered
        np.testing.assert_array_equal(d["pose"], src["pose"])
        assert list(d["source_shard"]) == [path.name] * len(d["pose"])
        np.testing.assert_array_equal(d["source_frame"], np.arange(len(d["pose"])))
        for i in range(len(d["pose"])):
            x0, y0, x1, y1 = d["occlusion_rects"][i, 0]
            assert not d["rgb"][i, y0:y1, x0:x1].any()
            visible = d["mask"][i].astype(bool).copy()
            visible[y0:y1, x0:x1] = False
            np.testing.assert_array_equal(d["visible_mask"][i], visible)
            measured = 1 - visible.sum() / d["mask"][i].sum()
            assert measured == pytest.approx(d["occlusion_fraction"][i], abs=1e-6)
    assert read_manifest(tmp_path / "occ")["frames"] == 78


def test_fixed_fraction_is_hit_within_one_percent(rendered, tmp_path):
    summary = occlude_dataset(rendered, tmp_path / "occ", low=0.3, high=0.3)
    fractions = np.concatenate([read_shard(p, ["occlusion_fraction"])["occlusion_fraction"]
                                for p in list_shards(tmp_path / "occ")])
    assert sum(r["unreachable"] for r in summary.results.values()) == 0
    assert np.all(np.abs(fractions - 0.3) <= 0.01)


def test_same_seed_same_bytes_other_seed_other_bytes(rendered, tmp_path):
    occlude_dataset(rendered, tmp_path / "a", seed=4, copies=2)
    occlude_dataset(rendered, tmp_path / "b", seed=4, copies=2, executor=LocalExecutor(workers=2))
    occlude_dataset(rendered, tmp_path / "c", seed=5, copies=2)
    a, b, c = hashes(tmp_path / "a"), hashes(tmp_path / "b"), hashes(tmp_path / "c")
    assert a == b
    shards = sorted(k for k in a if not k.startswith("meshes/"))
    assert shards == ["cup-00000-occ0.h5", "cup-00000-occ1.h5", "cup-00001-occ0.h5", "cup-00001-occ1.h5",
                      "manifest.json"]
    assert sorted(k for k in a if k.startswith("meshes/")) == sorted(   # the meshes travel with the frames
        f"meshes/{p.name}" for p in (rendered / "meshes").iterdir())
    assert a["cup-00000-occ0.h5"] != c["cup-00000-occ0.h5"]
    assert a["cup-00000-occ0.h5"] != a["cup-00000-occ1.h5"]  # copies differ


def test_resume_skips_complete_shards(rendered, tmp_path):
    occlude_dataset(rendered, tmp_path / "occ")
    (tmp_path / "occ" / "cup-00001.h5").unlink()
    again = occlude_dataset(rendered, tmp_path / "occ")
    assert again.skipped == ["cup-00000.h5"] and again.done == ["cup-00001.h5"]


def test_a_refusal_names_the_option_that_differs_and_both_values(rendered, tmp_path):
    out = tmp_path / "occ"
    occlude_dataset(rendered, out, high=0.6, seed=1)
    tail = f"; write into a new --out folder or delete {out}"
    for options, what in [(dict(high=0.9, seed=1), "max 0.6, not max 0.9"),
                          (dict(high=0.6, seed=2), "seed 1, not seed 2"),
                          (dict(low=0.1, high=0.6, seed=1), "min 0, not min 0.1"),
                          (dict(high=0.6, seed=1, rects=2), "rects 1, not rects 2")]:
        with pytest.raises(ShardError) as e:   # the library names the option by key, the CLI by flag
            occlude_dataset(rendered, out, **options)
        assert str(e.value) == f"{out / 'cup-00000.h5'} was made with {what}{tail}"
    r = run("occlude", rendered, "--out", out, "--max", "0.6", "--seed", "3")
    assert r.exit_code == 1 and r.output == (f"error: {out / 'cup-00000.h5'} was made with --seed 1, not --seed 3"
                                             f"{tail}\n")
    assert occlude_dataset(rendered, out, high=0.6, seed=1).skipped == ["cup-00000.h5", "cup-00001.h5"]


def test_a_refusal_names_an_input_made_again_otherwise(rendered, tmp_path):
    import shutil

    source = tmp_path / "source"
    shutil.copytree(rendered, source)
    occlude_dataset(source, tmp_path / "occ", high=0.6)
    spec = tmp_path / "cup.toml"
    spec.write_text(read_attrs(list_shards(source)[0])["spec"])
    shutil.rmtree(source)
    render_dataset(load_run_specs(spec_files=[spec], seed=7), source)   # the same names, another plan
    with pytest.raises(ShardError, match=r"occ/cup-00000.h5 was made from another version of its input "
                                         r"cup-00000.h5 \(made with plan [0-9a-f]{12}, which is now [0-9a-f]{12}\); "
                                         r"write into a new --out folder"):
        occlude_dataset(source, tmp_path / "occ", high=0.6)


def run(*args):
    return CliRunner().invoke(data_cli, [str(a) for a in args], catch_exceptions=False)


def test_cli_errors_are_one_line_and_write_nothing(rendered, tmp_path):
    out = tmp_path / "o"
    for args, message in [
        (["--max", "1.5"], "occlusion fractions must lie in [0, 1]: got --min 0.0, --max 1.5"),
        (["--min", "0.7", "--max", "0.6"], "--min 0.7 is above --max 0.6"),
    ]:
        r = run("occlude", rendered, "--out", out, *args)
        assert r.exit_code == 1 and r.output == f"error: {message}\n" and not out.exists()
    empty = tmp_path / "empty"
    empty.mkdir()
    r = run("occlude", empty, "--out", out)
    assert r.exit_code == 1 and "no shards (*.h5) in" in r.output and not out.exists()
    bad = tmp_path / "nomask"
    bad.mkdir()
    src = list_shards(rendered)[0]
    arrays = read_shard(src)
    arrays["mask"][:] = 0
    write_shard(bad / src.name, arrays, read_attrs(src))
    write_manifest(bad)
    r = run("occlude", bad, "--out", out)
    assert r.exit_code == 1 and "every mask is empty" in r.output and not out.exists()
    r = run("occlude", rendered, "--out", rendered)
    assert r.exit_code == 1 and "is the input folder" in r.output


def test_cli_occlude_runs(rendered, tmp_path):
    r = run("occlude", rendered, "--out", tmp_path / "o", "--max", "0.6", "--seed", "2")
    assert r.exit_code == 0, r.output
    assert "occluded 2 shards (78 frames)" in r.output and "0 frames could not reach" in r.output


def test_each_input_is_hashed_once_and_each_output_twice(rendered, tmp_path, monkeypatch):
    """occlude verifies every input before writing (check_inputs) and reads it again in its job:
    one SHA-256 pass over each input in all. Each output is hashed to seal it and once more for
    the manifest's file checksum, never read back."""
    import spm_data.io.files as files_module
    import spm_data.io.shards.manifest as manifest_module
    import spm_data.io.shards.seal as seal_module
    from spm_data.io.shards import forget_checks

    monkeypatch.setattr(seal_module, "RACY_SECONDS", -1.0)  # remember every verification (inputs just made)
    forget_checks()
    hashed, whole = [], []
    real, real_file = seal_module.content_digest, files_module.file_sha256
    monkeypatch.setattr(seal_module, "content_digest", lambda p: hashed.append(Path(p).name) or real(p))
    monkeypatch.setattr(manifest_module, "file_sha256", lambda p: whole.append(Path(p).name) or real_file(p))
    occlude_dataset(rendered, tmp_path / "occ", seed=3)
    inputs = [p.name for p in list_shards(rendered)]
    outputs = [".{}.partial".format(name) for name in inputs]  # sealed before the os.replace
    assert sorted(hashed) == sorted(inputs + outputs)
    assert sorted(whole) == sorted(inputs)  # the outputs' names, for the manifest
    assert read_manifest(tmp_path / "occ")["shards"][0]["sha256"] == file_sha256(tmp_path / "occ" / inputs[0])


def test_shards_occluded_in_a_spawned_worker_are_the_same_bytes(rendered, tmp_path, monkeypatch):
    """The jobs run in a spawned worker (which takes the parent's check of each input) give the
    bytes this process gives; occlude_dataset with --workers 2 mixes the two."""
    import spm_data.io.shards.seal as seal_module
    from spm_data.pipelines.occlude_jobs import check_inputs, occlude_shard, plan_occlusion
    from spm_data.jobs.shard_runs import run_shard_jobs

    monkeypatch.setattr(seal_module, "RACY_SECONDS", -1.0)  # the inputs were just made: remember their checks
    here = occlude_dataset(rendered, tmp_path / "here", seed=6, copies=2)
    jobs = plan_occlusion(check_inputs(rendered, tmp_path / "there"), tmp_path / "there", 0.0, 0.6, copies=2, seed=6)
    assert all(job.verified is not None and len(job.verified[1]) == 64 for job in jobs)
    there = run_shard_jobs(occlude_shard, jobs, tmp_path / "there", executor=LocalExecutor(workers=1),
                           in_process=False, verb="occluded")
    assert sorted(there.done) == sorted(here.done) and len(there.done) == 4
    assert hashes(tmp_path / "there") == hashes(tmp_path / "here")
