"""Objects are meshes: one obj_id per distinct mesh, names that say so, ids kept across exports,
and the frame -> (scene, image, object) rule the export and the results file share."""

import json
import warnings

from click.testing import CliRunner

from cli import data_cli
from spm_data.pipelines.merge import merge_folders
from spm_data.pipelines.render_jobs import load_run_specs, render_dataset
from spm_data.errors import SpmWarning
from spm_data.formats.bop.export import export_bop
from spm_data.formats.bop.ids import OBJECTS_FILE, frame_ids, load_objects, save_objects

SPEC = """class = "{cls}"
seed = {seed}
[mesh]
generator = "{gen}"
instances = 2
[camera]
azimuth = [0, 10, 5]
elevation = [0, 0, 5]
distances = [0.7]
[image]
width = 32
height = 32
[render]
renderer = "pyrender"
"""


def render(tmp_path, name, classes):
    """Render ``classes`` [(class, generator, seed)] into tmp_path/name; returns the folder."""
    specs = tmp_path / f"{name}-specs"
    specs.mkdir()
    for cls, gen, seed in classes:
        (specs / f"{cls}.toml").write_text(SPEC.format(cls=cls, gen=gen, seed=seed))
    render_dataset(load_run_specs(all_classes=True, specs_dir=specs), tmp_path / name)
    return tmp_path / name


def test_two_meshes_under_one_name_are_two_objects_with_a_warning_at_merge(tmp_path):
    a = render(tmp_path, "a", [("cup", "cup", 1)])
    b = render(tmp_path, "b", [("cup", "cup", 2)])   # another seed: other cups, the same names
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        merge_folders([a, b], tmp_path / "m")
    said = [str(w.message) for w in seen if issubclass(w.category, SpmWarning)]
    assert len(said) == 1 and "2 name(s) stand for different meshes" in said[0] and "cup/cup-000 (2 meshes)" in said[0]
    export_bop(tmp_path / "m", tmp_path / "bop")
    objects = load_objects(tmp_path / "bop")
    assert len(objects) == 4 and len({o["mesh"] for o in objects.values()}) == 4
    names = sorted(o["instance"] for o in objects.values())
    assert all("~" in n for n in names) and len(set(names)) == 4
    assert {n.split("~")[0] for n in names} == {"cup-000", "cup-001"}
    assert len(list((tmp_path / "bop" / "models").glob("obj_*.ply"))) == 4


def test_one_mesh_under_two_names_is_one_object(tmp_path):
    cup = render(tmp_path, "cup", [("cup", "cup", 5)])
    mug = render(tmp_path, "mug", [("mug", "cup", 5)])   # the same generator and seed: the same meshes
    merge_folders([cup, mug], tmp_path / "m")
    export_bop(tmp_path / "m", tmp_path / "bop")
    objects = load_objects(tmp_path / "bop")
    assert len(objects) == 2
    assert sorted(tuple(o["names"]) for o in objects.values()) == [("cup/cup-000", "mug/cup-000"),
                                                                   ("cup/cup-001", "mug/cup-001")]
    gt = json.loads((tmp_path / "bop" / "train" / "000000" / "scene_gt.json").read_text())
    assert len(gt) == 6   # 3 views x 2 renders of the one mesh


def test_frame_ids_are_the_exports_and_a_merge_exports_the_same_models(tmp_path):
    a = render(tmp_path, "a", [("cup", "cup", 1), ("box", "box", 1)])
    merge_folders([a], tmp_path / "m")
    export_bop(a, tmp_path / "bop-a")
    export_bop(tmp_path / "m", tmp_path / "bop-m")
    for sub in ("models", "models_eval"):
        names = sorted(p.name for p in (tmp_path / "bop-a" / sub).iterdir())
        assert names == sorted(p.name for p in (tmp_path / "bop-m" / sub).iterdir()) and len(names) >= 5
        for name in names:
            assert (tmp_path / "bop-a" / sub / name).read_bytes() == (tmp_path / "bop-m" / sub / name).read_bytes()
    for folder, export in ((a, "bop-a"), (tmp_path / "m", "bop-m")):
        ids = frame_ids(folder)
        assert len(ids.obj_id) == 12
        for obj, scene, im in zip(ids.obj_id, ids.scene_id, ids.im_id):
            gt = json.loads((tmp_path / export / "train" / f"{scene:06d}" / "scene_gt.json").read_text())
            assert gt[str(im)][0]["obj_id"] == obj


def test_ids_from_keeps_every_id_on_a_subset_export(tmp_path):
    full = render(tmp_path, "full", [("ball", "ball", 1), ("box", "box", 1), ("car", "car", 1), ("cup", "cup", 1)])
    part = render(tmp_path, "part", [("ball", "ball", 1), ("car", "car", 1), ("cup", "cup", 1)])
    export_bop(full, tmp_path / "bop-full")
    r = CliRunner().invoke(data_cli, ["export", "bop", str(part), "--out", str(tmp_path / "bop-part"),
                                      "--ids-from", str(tmp_path / "bop-full")])
    assert r.exit_code == 0, r.output
    before, after = load_objects(tmp_path / "bop-full"), load_objects(tmp_path / "bop-part")
    kept = {k: v["mesh"] for k, v in after.items()}
    assert len(kept) == 6 and all(before[k]["mesh"] == digest for k, digest in kept.items())
    plain = load_objects(export_bop(part, tmp_path / "bop-plain") and tmp_path / "bop-plain")
    assert sorted(plain) == [1, 2, 3, 4, 5, 6] and sorted(after) != [1, 2, 3, 4, 5, 6]
    r = CliRunner().invoke(data_cli, ["export", "bop", str(part), "--out", str(tmp_path / "x"),
                                      "--ids-from", str(tmp_path / "nowhere")])
    assert r.exit_code == 1 and len(r.output.strip().splitlines()) == 1 and "no such file" in r.output


def test_objects_json_is_saved_beside_where_it_is_loaded_back(tmp_path):
    names = {2: {"class": "cup", "instance": "cup-1", "instance_id": 1, "mesh": "ab12"},
             1: {"class": "box", "instance": "box-0", "instance_id": 0}}
    path = save_objects(tmp_path, names)
    assert path == tmp_path / OBJECTS_FILE and list(json.loads(path.read_text())) == ["1", "2"]   # by obj_id
    assert load_objects(tmp_path) == names and load_objects(path) == names
