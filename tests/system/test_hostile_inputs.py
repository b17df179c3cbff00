"""The hostile inputs of issue 22, each one line and exit 1 with nothing written or left
behind: a class name that cannot name a file, a seed past 2**63, a 300-byte --out, a
manifest with values of the wrong type, a folder merged with itself, --rects 10**6, a
full disk in occlude's object copy, and a corrupt shard whose mtime was put back
(refused by train and evaluate, not served from the feature cache)."""

import json
import os
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from cli import data_cli, model_cli
from spm_data.io.shards import write_manifest, write_shard
from tests.helpers import coil_image, flip_stored_byte, make_arrays, png_bytes


def one_error(result) -> str:
    assert result.exit_code == 1, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exc_info
    errors = [line for line in result.output.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1 and "Traceback" not in result.output, result.output
    return errors[0]


def run(cli, *args):
    return CliRunner().invoke(cli, [str(a) for a in args])


@pytest.fixture
def folder(tmp_path):
    """Two shards of 4 frames (cup) with a manifest."""
    d = tmp_path / "in"
    d.mkdir()
    for k in range(2):
        arrays = make_arrays(n=4, h=16, w=16, seed=k)
        arrays["class_name"], arrays["source"] = ["cup"] * 4, ["synthetic"] * 4
        arrays["mask"] = np.ones((4, 16, 16), np.uint8)
        arrays["occlusion_fraction"] = np.zeros(4, np.float32)
        arrays["occlusion_rects"] = np.zeros((4, 1, 4), np.int32)
        write_shard(d / f"cup-{k:05d}.h5", arrays, {"renderer": "x", "seed": 0})
    write_manifest(d)
    return d


def test_a_class_that_cannot_name_a_file_is_a_spec_error(tmp_path):
    spec = tmp_path / "cup.toml"
    spec.write_text('class = ".cup"\n[render]\nrenderer = "pyrender"\n')
    line = one_error(run(data_cli, "render", "--spec", spec, "--out", tmp_path / "out"))
    assert "class: '.cup' cannot name a shard file (CLASS-00000.h5)" in line
    assert not (tmp_path / "out").exists()


def test_a_seed_past_2_63_is_one_line(folder, tmp_path):
    spec = tmp_path / "cup.toml"
    spec.write_text('class = "cup"\n[render]\nrenderer = "pyrender"\n')
    line = one_error(run(data_cli, "render", "--spec", spec, "--out", tmp_path / "out", "--seed", 2**70))
    assert f"seed: expected an integer in [0, {2**63 - 1}], got {2**70}" in line
    line = one_error(run(data_cli, "occlude", "--in", folder, "--out", tmp_path / "occ", "--seed", 2**70))
    assert line == f"error: --seed {2**70}: expected an integer in [0, {2**63 - 1}]"
    assert not (tmp_path / "out").exists() and not (tmp_path / "occ").exists()


def test_rects_are_bounded(folder, tmp_path):
    line = one_error(run(data_cli, "occlude", "--in", folder, "--out", tmp_path / "occ", "--rects", 1000000))
    assert line == "error: --rects 1000000: at most 64 rectangles per frame" and not (tmp_path / "occ").exists()


@pytest.mark.parametrize("command", ["occlude", "merge", "export"])
def test_an_out_name_too_long_for_the_file_system_is_one_line(folder, tmp_path, command):
    out = tmp_path / ("x" * 300)
    args = {"occlude": ["occlude", "--in", folder, "--out", out], "merge": ["merge", folder, "--out", out],
            "export": ["export", "bop", folder, "--out", out]}[command]
    line = one_error(run(data_cli, *args))
    assert "the name xxxxxxxxxxxxxxxxxxxxxxxx... is 300 bytes, over the" in line and "give a shorter name" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in"]


@pytest.mark.parametrize("change, command", [({"missing": 7}, "occlude"), ({"shards": [None]}, "validate"),
                                             ({"missing": "abc"}, "merge")])
def test_a_manifest_with_values_of_the_wrong_type_is_one_line(folder, tmp_path, change, command):
    manifest = folder / "manifest.json"
    manifest.write_text(json.dumps({**json.loads(manifest.read_text()), **change}))
    args = {"occlude": ["occlude", "--in", folder, "--out", tmp_path / "occ"], "validate": ["validate", folder],
            "merge": ["merge", folder, "--out", tmp_path / "occ"]}[command]
    r = run(data_cli, *args)
    if command == "validate":  # validate lists problems
        assert r.exit_code == 1 and "Traceback" not in r.output and "shards[0] is null" in r.output, r.output
    else:
        assert "the manifest is damaged" in one_error(r)
    assert not (tmp_path / "occ").exists()


def test_a_folder_merged_with_itself_is_said_so_not_called_corrupt(folder, tmp_path):
    line = one_error(run(data_cli, "merge", folder, folder, "--out", tmp_path / "m"))
    assert line == f"error: cup-00000.h5 is in the inputs twice ({folder} and {folder}); give each folder once"
    assert "corrupt" not in line and not (tmp_path / "m").exists()


@pytest.mark.parametrize("command", ["validate", "info", "occlude", "merge", "export", "train"])
@pytest.mark.parametrize("how", ["name", "content"])
def test_a_shard_listed_twice_or_copied_is_refused_by_every_reader(folder, tmp_path, command, how):
    """One rule, every reader (issue 35): no frame is read twice. A name listed twice in the
    manifest, or a copy of a shard under another name, is one line, and nothing is written."""
    manifest = folder / "manifest.json"
    payload = json.loads(manifest.read_text())
    if how == "name":
        payload["shards"].append(dict(payload["shards"][0]))
        expected = "cup-00000.h5 is listed twice"
    else:
        shutil.copy(folder / "cup-00000.h5", folder / "cup-00009.h5")
        payload["shards"].append({**payload["shards"][0], "file": "cup-00009.h5"})
        expected = "cup-00000.h5 and cup-00009.h5 have the same content (SHA-256"
    manifest.write_text(json.dumps(payload))
    out = tmp_path / "out"
    args = {"validate": [data_cli, "validate", folder], "info": [data_cli, "info", folder],
            "occlude": [data_cli, "occlude", "--in", folder, "--out", out],
            "merge": [data_cli, "merge", folder, "--out", out],
            "export": [data_cli, "export", "bop", folder, "--out", out],
            "train": [model_cli, "train", folder, "--out", out]}[command]
    r = run(*args)
    if command == "validate":  # validate lists problems
        assert r.exit_code == 1 and "Traceback" not in r.output and expected in r.output, r.output
    else:
        assert expected in one_error(r)
    assert not out.exists()


@pytest.fixture(scope="module")
def template_model(tmp_path_factory):
    """A reference model file (spm evaluate loads it before reading shards)."""
    from tests.system.test_flip_scan import model

    return model.__wrapped__(tmp_path_factory)


def reader_commands(folder, out, model):
    return {"info": [data_cli, "info", folder], "occlude": [data_cli, "occlude", "--in", folder, "--out", out],
            "merge": [data_cli, "merge", folder, "--out", out],
            "export": [data_cli, "export", "bop", folder, "--out", out],
            "train": [model_cli, "train", folder, "--out", out],
            "hist": [data_cli, "hist", folder, "--out", out.with_suffix(".png")],
            "evaluate": [model_cli, "evaluate", "--model", model, "--shards", folder]}


@pytest.mark.parametrize("command", ["validate", "info", "occlude", "merge", "export", "train", "hist", "evaluate"])
@pytest.mark.parametrize("sha256", ["wrong", "none"])
def test_a_copy_is_refused_from_its_bytes_whatever_the_manifest_says(folder, tmp_path, template_model, command,
                                                                     sha256):
    """Issue 47: a byte copy listed with a wrong or no sha256 in the manifest was read twice by
    every reader, exit 0 (train: 16 frames for 8). Decided from the shards' own digests now."""
    shutil.copy(folder / "cup-00000.h5", folder / "copy.h5")
    payload = json.loads((folder / "manifest.json").read_text())
    entry = {**payload["shards"][0], "file": "copy.h5"}
    entry.pop("sha256") if sha256 == "none" else entry.update(sha256="0" * 64)
    payload["shards"].append(entry)
    (folder / "manifest.json").write_text(json.dumps(payload))
    out = tmp_path / "out"
    if command == "validate":   # validate lists problems
        r = run(data_cli, "validate", folder)
        assert r.exit_code == 1 and "manifest.json: cup-00000.h5 and copy.h5 have the same content (SHA-256" \
            in r.output and "Traceback" not in r.output, r.output
        return
    line = one_error(run(*reader_commands(folder, out, template_model)[command]))
    assert "cup-00000.h5 and copy.h5 have the same content (SHA-256" in line, line
    assert not out.exists() and not out.with_suffix(".png").exists()


@pytest.mark.parametrize("command", ["info", "occlude", "merge", "export", "train", "hist", "evaluate"])
def test_a_merge_of_a_folder_beside_it_is_refused_frame_by_frame(folder, tmp_path, template_model, command):
    """A folder holding `merge A` and A's shards (under one tree, or merged again): each frame
    would be read twice; refused by every reader, from the frames' own bytes."""
    tree = tmp_path / "tree"
    shutil.copytree(folder, tree / "a")
    assert run(data_cli, "merge", folder, "--out", tree / "m").exit_code == 0
    out = tmp_path / "out"
    args = reader_commands(tree, out, template_model)[command]
    if command not in ("train", "evaluate"):   # commands of one folder: A's shards listed in M's manifest
        for shard in (tree / "a").glob("*.h5"):
            shutil.copy(shard, tree / "m" / shard.name)
        payload = json.loads((tree / "m" / "manifest.json").read_text())
        payload["shards"] += json.loads((tree / "a" / "manifest.json").read_text())["shards"]
        (tree / "m" / "manifest.json").write_text(json.dumps(payload))
        args = reader_commands(tree / "m", out, template_model)[command]
    line = one_error(run(*args))
    assert "(the same image, camera and names), so it would be read twice" in line, line
    assert not out.exists() and not out.with_suffix(".png").exists()


def test_merging_a_merge_of_a_folder_with_it_is_refused(folder, tmp_path):
    assert run(data_cli, "merge", folder, "--out", tmp_path / "m").exit_code == 0
    line = one_error(run(data_cli, "merge", folder, tmp_path / "m", "--out", tmp_path / "mm"))
    assert line.startswith(f"error: merge: frame 0 of {tmp_path}/m/merged-16x16-00000.h5 is frame 0 of "
                           f"{folder}/cup-00000.h5 (the same image, camera and names), so it would be read twice; "
                           "give each folder once"), line
    assert not (tmp_path / "mm").exists()


def test_merging_a_folder_with_a_copy_of_itself_is_refused(folder, tmp_path):
    shutil.copytree(folder, tmp_path / "copy")
    line = one_error(run(data_cli, "merge", folder, tmp_path / "copy", "--out", tmp_path / "m"))
    assert line.startswith(f"error: merge: {folder}/cup-00000.h5 and {tmp_path}/copy/cup-00000.h5 have the same "
                           "content (SHA-256 ") and line.endswith("give each folder once (a copy of a folder, or a "
                                                                  "merge of it, holds the same frames)")
    assert not (tmp_path / "m").exists()


def test_a_full_disk_in_occludes_object_copy_is_one_line(folder, tmp_path, monkeypatch):
    import h5py

    def full(*args, **kwargs):
        raise RuntimeError("Unable to synchronously copy object (file write failed: time = Mon Nov 23 2026, "
                           "filename = 'x', file descriptor = 7, errno = 28, error message = 'No space left on "
                           "device', buf = 0x1, total write size = 4096, bytes this sub-write = 4096)")

    monkeypatch.setattr(h5py.Group, "copy", full)
    r = run(data_cli, "occlude", "--in", folder, "--out", tmp_path / "occ")
    assert r.exit_code == 1 and "Traceback" not in r.output and "Unable to" not in r.output, r.output
    occ = tmp_path / "occ"
    assert [line.strip() for line in r.output.splitlines() if "failed cup" in line] == [
        f"failed cup-0000{k}.h5: could not write shard {occ}/cup-0000{k}.h5: No space left on device" for k in (0, 1)]
    assert not occ.exists()  # every shard failed: the folder it made is removed


@pytest.mark.parametrize("command", ["occlude", "merge"])
def test_a_full_disk_leaves_no_mesh_store_behind(small_specs_dir, tmp_path, monkeypatch, command):
    """Issue 47: a rendered folder's meshes travel into OUT/meshes/ before each shard lands; a
    full disk failed every shard and left OUT/meshes/*.npz, though the folder it made is removed."""
    import h5py

    from spm_data.pipelines import merge as merge_module
    from spm_data.errors import ShardError
    from spm_data.pipelines.render_jobs import load_run_specs, render_dataset

    render_dataset(load_run_specs(["cup"], specs_dir=small_specs_dir), tmp_path / "r", limit=4)
    error = ("Unable to synchronously copy object (file write failed: errno = 28, error message = 'No space left "
             "on device')")

    def full(*args, **kwargs):
        raise RuntimeError(error)

    monkeypatch.setattr(h5py.Group, "copy", full)                  # occlude's object copy
    def merge_full(path, *args, **kwargs):   # what the writer raises for a full disk (io/shards/writer.py)
        raise ShardError(f"could not write shard {path}: No space left on device")

    monkeypatch.setattr(merge_module, "write_shard", merge_full)
    args = {"occlude": ["occlude", "--in", tmp_path / "r", "--out", tmp_path / "out"],
            "merge": ["merge", tmp_path / "r", "--out", tmp_path / "out"]}[command]
    r = run(data_cli, *args)
    assert r.exit_code == 1 and "Traceback" not in r.output and "failed " in r.output, r.output
    assert not (tmp_path / "out").exists(), sorted(p.name for p in (tmp_path / "out").rglob("*"))


@pytest.fixture(scope="module")
def trained(model_shards, tmp_path_factory):
    """A copy of model_shards (with their cached features, keyed by content), trained on, and its model."""
    root = tmp_path_factory.mktemp("trained")
    shards = shutil.copytree(model_shards, root / "shards", ignore=shutil.ignore_patterns("report"))
    r = run(model_cli, "train", "--shards", shards, "--report", root / "report", "--runs", "1", "--protocol", "views",
            "--ellipse", "direct", "--methods", "spm")
    assert r.exit_code == 0, r.output
    return shards, root / "report" / "model.npz"


def test_a_corrupt_shard_with_its_mtime_put_back_is_refused_by_train_and_evaluate(trained, tmp_path):
    shards, model = trained
    shard = sorted(shards.glob("*.h5"))[0]
    before = shard.read_bytes()
    st = shard.stat()
    try:
        flip_stored_byte(shard, "pose")
        os.utime(shard, ns=(st.st_atime_ns, st.st_mtime_ns))  # bit rot, cp -p, rsync -t: size and mtime kept
        expected = f"{shard}: field 'pose' fails its checksum"
        line = one_error(run(model_cli, "train", "--shards", shards, "--report", tmp_path / "r", "--runs", "1",
                             "--protocol", "views", "--ellipse", "direct", "--methods", "spm"))
        assert expected in line and not (tmp_path / "r").exists()
        assert expected in one_error(run(model_cli, "evaluate", "--model", model, "--shards", shards))
    finally:
        shard.write_bytes(before)


def test_an_unreadable_or_looping_shard_is_one_problem_in_validate_and_info_is_not_whole(folder, monkeypatch):
    """validate: PermissionError from hashing (simulated: tests run as root) and a symlink loop
    each one problem line, never a traceback; info describes a folder with a cut shard but exits 1."""
    from spm_data.pipelines import validate

    real = validate.file_sha256

    def denied(path):
        if path.name == "cup-00000.h5":
            raise PermissionError(13, "Permission denied")
        return real(path)

    monkeypatch.setattr(validate, "file_sha256", denied)
    r = run(data_cli, "validate", folder)
    assert r.exit_code == 1 and "Traceback" not in r.output, r.output
    assert "  cup-00000.h5: cannot be read (Permission denied); fix it or replace it" in r.output.splitlines()
    monkeypatch.undo()
    loop = folder / "cup-00001.h5"
    loop.unlink()
    loop.symlink_to(loop.name)
    r = run(data_cli, "validate", folder)
    assert r.exit_code == 1 and "Traceback" not in r.output and "Too many levels of symbolic links" in r.output
    data = (folder / "cup-00000.h5").read_bytes()
    (folder / "cup-00000.h5").write_bytes(data[: len(data) // 2])
    r = run(data_cli, "info", folder)
    assert r.exit_code == 1 and "Traceback" not in r.output
    assert r.output.splitlines()[-1] == (f"error: {folder}: 2 problems noted above; the folder is not whole: run "
                                         f"`spm-data validate {folder}` for the details")


@pytest.mark.parametrize("command", ["render", "occlude", "merge", "export"])
def test_an_out_path_too_long_as_a_whole_is_one_line(folder, tmp_path, command):
    """Every name fits (200 bytes) but the whole path is over PATH_MAX: one line, nothing made
    (render once checked the last name only and failed with a traceback deep inside)."""
    out = tmp_path.joinpath(*["d" * 200] * 21)
    spec = tmp_path / "cup.toml"
    spec.write_text('class = "cup"\n[render]\nrenderer = "pyrender"\n')
    args = {"render": ["render", "--spec", spec, "--out", out, "--limit", 2],
            "occlude": ["occlude", "--in", folder, "--out", out], "merge": ["merge", folder, "--out", out],
            "export": ["export", "bop", folder, "--out", out]}[command]
    line = one_error(run(data_cli, *args))
    assert "and with the files written inside it would be over the 4096 a path can have here; give a shorter path" \
        in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cup.toml", "in"]


def test_a_class_name_render_would_refuse_is_refused_by_merge_and_the_importers(folder, tmp_path):
    rule = "'a/b' cannot name a shard file (CLASS-00000.h5): expected a non-empty name"
    line = one_error(run(data_cli, "merge", folder, "--out", tmp_path / "m", "--rename", "cup=a/b"))
    assert line.startswith(f"error: --rename cup=a/b: {rule}") and not (tmp_path / "m").exists()
    photos = tmp_path / "coil"
    photos.mkdir()
    for view in range(2):
        (photos / f"obj1__{view}.png").write_bytes(png_bytes(coil_image(1, 5 * view)))
    (tmp_path / "map.csv").write_text("1,a/b\n")
    line = one_error(run(data_cli, "import", "coil20", photos, "--out", tmp_path / "o", "--class-map",
                         tmp_path / "map.csv"))
    assert f"class {rule}" in line and line.endswith("give another class name (nothing was written)")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("option, args", [
    ("--copies", ["occlude", "--in", "{folder}", "--out", "{out}", "--copies", 10**9]),   # ran until killed
    ("--limit", ["render", "--class", "cup", "--out", "{out}", "--limit", 10**7 + 1]),
    ("--frames-per-shard", ["merge", "{folder}", "--out", "{out}", "--frames-per-shard", 65537]),
    ("--frames", ["show", "{folder}/cup-00000.h5", "--out", "{out}", "--frames", 1025]),
    ("--workers", ["occlude", "--in", "{folder}", "--out", "{out}", "--workers", 1025]),
    ("--recycle-after", ["render", "--class", "cup", "--out", "{out}", "--recycle-after", 10**6 + 1]),
    ("--runs", ["train", "{folder}", "--out", "{out}", "--runs", 101]),
    ("--gamma", ["train", "{folder}", "--out", "{out}", "--gamma", 257]),
])
def test_count_options_have_an_upper_bound_checked_before_work(folder, tmp_path, option, args):
    out = tmp_path / "out"
    r = run(model_cli if args[0] == "train" else data_cli, *[str(a).format(folder=folder, out=out) for a in args])
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert f"Invalid value for '{option}'" in r.output and "is not in the range" in r.output
    assert not out.exists()
