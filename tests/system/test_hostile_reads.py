"""Hostile reads: a flipped byte anywhere, a deleted shard, a stray shard, a folder
still being written. Every reader refuses (or reports), names the shard and the
field, and writes nothing."""

import shutil
import signal
import subprocess
import sys

import pytest
from click.testing import CliRunner

from cli import data_cli, model_cli
from tests.helpers import flip_stored_byte, reaped, wait_for
from spm_data.errors import ShardError
from spm_data.io.locking import lock_owner
from spm_data.pipelines.render_jobs import load_run_specs, render_dataset
from spm_data.io.shards import FIELDS, list_shards, read_manifest, read_shard, write_shard

SPEC = ('class = "{cls}"\nseed = 4\n[mesh]\ninstances = 2\n[camera]\nazimuth = [0, 35, 5]\n'
        'elevation = [20, 20, 5]\ndistances = [0.6]\n[image]\nwidth = 96\nheight = 96\n'
        '[render]\nrenderer = "pyrender"\nframes_per_shard = 8\n')


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    """cup and box, 2 instances x 8 views each at 96 px: 4 shards of 8 frames."""
    specs = tmp_path_factory.mktemp("specs")
    for cls in ("cup", "box"):
        (specs / f"{cls}.toml").write_text(SPEC.format(cls=cls))
    out = tmp_path_factory.mktemp("clean") / "shards"
    render_dataset(load_run_specs(all_classes=True, specs_dir=specs), out)
    return out


def copy(clean, tmp_path):
    return shutil.copytree(clean, tmp_path / "in")


def flip_text(path, text: bytes):
    data = bytearray(path.read_bytes())
    at = data.index(text) + 2
    data[at] ^= 0x01
    path.write_bytes(bytes(data))


def one_error(result):
    assert result.exit_code == 1, result.output
    assert "Traceback" not in result.output
    errors = [line for line in result.output.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1, result.output
    return errors[0]


def run(cli, *args):
    return CliRunner().invoke(cli, [str(a) for a in args])


COMPRESSED = ("rgb", "depth", "mask")


@pytest.mark.parametrize("field", list(FIELDS))
def test_a_flipped_byte_in_any_field_is_refused_by_occlude_naming_it(clean, tmp_path, field):
    src = copy(clean, tmp_path)
    flip_stored_byte(src / "cup-00000.h5", field)
    with pytest.raises(ShardError, match=f"cup-00000.h5: field '{field}' fails its checksum"):
        read_shard(src / "cup-00000.h5", [field])
    line = one_error(run(data_cli, "occlude", src, "--out", tmp_path / "occ"))
    assert f"cup-00000.h5: field '{field}' fails its checksum" in line
    assert not (tmp_path / "occ").exists()


@pytest.mark.parametrize("field", ["rgb", "K", "pose", "class_name"])
def test_every_reader_refuses_a_flipped_byte(clean, tmp_path, field):
    src = copy(clean, tmp_path)
    flip_stored_byte(src / "box-00001.h5", field)
    expected = f"box-00001.h5: field '{field}' fails its checksum"
    assert expected in one_error(run(data_cli, "merge", src, "--out", tmp_path / "merged"))
    assert expected in one_error(run(data_cli, "export", "bop", src, "--out", tmp_path / "bop"))
    assert not (tmp_path / "merged").exists() and not list(tmp_path.glob("bop*"))
    r = run(data_cli, "validate", src)
    assert r.exit_code == 1 and expected in r.output
    if field in ("rgb", "K", "pose", "class_name"):  # what training reads
        line = one_error(run(model_cli, "train", src, "--out", tmp_path / "report", "--runs", "1"))
        assert expected in line and not (tmp_path / "report").exists()


def test_a_flipped_byte_in_an_attribute_is_refused(clean, tmp_path):
    src = copy(clean, tmp_path)
    flip_text(src / "cup-00001.h5", b"frames_per_shard")  # inside the spec text attribute
    line = one_error(run(data_cli, "occlude", src, "--out", tmp_path / "occ"))
    assert "cup-00001.h5: attribute 'spec' fails its checksum" in line
    assert not (tmp_path / "occ").exists()


def test_a_derived_shard_never_launders_corruption(clean, tmp_path):
    """What occlude copies verbatim (depth, poses...) is verified first, so an
    occluded copy can't hide a bad byte of its source behind a new checksum."""
    src = copy(clean, tmp_path)
    flip_stored_byte(src / "cup-00000.h5", "depth")
    line = one_error(run(data_cli, "occlude", src, "--out", tmp_path / "occ"))
    assert "cup-00000.h5: field 'depth' fails its checksum" in line
    assert not (tmp_path / "occ").exists()


def test_a_missing_shard_is_an_error_and_allow_partial_skips_it(clean, tmp_path):
    src = copy(clean, tmp_path)
    (src / "box-00000.h5").unlink()
    line = one_error(run(data_cli, "occlude", src, "--out", tmp_path / "occ"))
    assert "box-00000.h5 is listed in manifest.json but missing" in line and not (tmp_path / "occ").exists()
    assert "box-00000.h5 is listed" in one_error(run(data_cli, "merge", src, "--out", tmp_path / "m"))
    r = run(data_cli, "occlude", src, "--out", tmp_path / "occ", "--allow-partial")
    assert r.exit_code == 0, r.output
    assert "warning: " in r.output and "box-00000.h5 is listed in manifest.json but missing; skipped" in r.output
    assert read_manifest(tmp_path / "occ")["frames"] == 24


def test_a_stray_shard_is_reported_and_ignored_never_adopted(clean, tmp_path):
    src = copy(clean, tmp_path)
    stray = read_shard(src / "cup-00000.h5")
    write_shard(src / "stray.h5", stray, {"renderer": "x", "seed": 0})
    r = run(data_cli, "occlude", src, "--out", tmp_path / "occ")
    assert r.exit_code == 0, r.output
    assert "warning: " in r.output and "ignoring 1 shard(s) manifest.json does not list (stray.h5)" in r.output
    assert read_manifest(tmp_path / "occ")["frames"] == 32
    assert not (tmp_path / "occ" / "stray.h5").exists()
    # A re-run of render into the folder leaves the stray out of its manifest.
    specs = tmp_path / "specs"
    specs.mkdir()
    (specs / "cup.toml").write_text(SPEC.format(cls="cup"))
    (specs / "box.toml").write_text(SPEC.format(cls="box"))
    render_dataset(load_run_specs(all_classes=True, specs_dir=specs), src)
    assert "stray.h5" not in [e["file"] for e in read_manifest(src)["shards"]]


def test_no_manifest_is_refused_unless_allow_partial(clean, tmp_path):
    src = copy(clean, tmp_path)
    (src / "manifest.json").unlink()
    line = one_error(run(data_cli, "hist", src, "--out", tmp_path / "h.png"))
    assert "no manifest.json, so no finished run made these 4 shards" in line and not (tmp_path / "h.png").exists()
    r = run(data_cli, "hist", src, "--out", tmp_path / "h.png", "--allow-partial")
    assert r.exit_code == 0 and "warning: " in r.output and (tmp_path / "h.png").is_file()


def test_a_folder_being_written_is_refused_with_who_writes_it(tmp_path):
    spec = tmp_path / "cup.toml"
    spec.write_text('class = "cup"\n[image]\nwidth = 64\nheight = 64\n[render]\nrenderer = "pyrender"\n'
                    'frames_per_shard = 64\n')
    out = tmp_path / "out"
    cmd = [sys.executable, "-c", "import cli; cli.data_cli()", "render", "--spec", str(spec), "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    with reaped(proc):
        wait_for(lambda: out.is_dir() and list_shards(out) and lock_owner(out), "a shard and the lock", proc=proc)
        proc.send_signal(signal.SIGSTOP)  # hold the run still while we read
        try:
            line = one_error(run(data_cli, "occlude", out, "--out", tmp_path / "occ"))
            assert f"is still being written by pid {proc.pid} on host" in line
            assert "--allow-partial" in line and not (tmp_path / "occ").exists()
            line = one_error(run(model_cli, "train", out, "--out", tmp_path / "r"))
            assert f"is still being written by pid {proc.pid}" in line
            done = len(list_shards(out))
            r = run(data_cli, "occlude", out, "--out", tmp_path / "occ", "--allow-partial")
            assert r.exit_code == 0, r.output
            assert f"warning: {out}/ is still being written by pid {proc.pid}" in r.output
            assert f"occluded {done} shard{'' if done == 1 else 's'} (" in r.output
        finally:
            proc.send_signal(signal.SIGCONT)
            proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=120)
