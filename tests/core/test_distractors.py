"""[distractors]: placement in front of the target at the drawn visible fraction."""

import numpy as np
import pytest

from spm_data.core.distractors import _solve, place_distractors, pool_names
from spm_data.core.instances import load_instance
from spm_data.core.paths import camera_path
from spm_data.core.raster import project
from spm_data.core.specs import parse_spec
from spm_data.errors import SpecError, SpmError
from spm_data.render.base import spec_intrinsics


def cluttered(count=2, visible="[0.0, 1.0]", extra=""):
    return parse_spec(f'class = "cup"\n[distractors]\ncount = {count}\nvisible = {visible}\n'
                      f'classes = ["box", "ball"]\ninstances = 3\n{extra}')


def frames(spec, n=24):
    R, t = camera_path(spec.camera).poses(np.arange(0, 37 * n, 37))
    return R, t


def test_the_placed_distractors_leave_the_drawn_fraction_visible():
    spec = cluttered()
    mesh = load_instance(spec, 0)
    R, t = frames(spec)
    draws = []
    for i in range(len(R)):
        p = place_distractors(spec, mesh, R[i], t[i], spec_intrinsics(spec), 0, i)
        assert len(p.distractors) == 2 and p.amodal.sum() > 500
        assert abs(p.visible - p.visible_target) <= 0.01, (i, p.visible, p.visible_target)
        draws.append(p.visible_target)
    assert min(draws) < 0.2 and max(draws) > 0.8  # the whole [0, 1] range is reached


def test_distractors_are_wholly_between_the_camera_and_the_target():
    spec = cluttered(count=3, visible="[0.2, 0.6]")
    mesh = load_instance(spec, 1)
    R, t = frames(spec, 10)
    for i in range(len(R)):
        p = place_distractors(spec, mesh, R[i], t[i], spec_intrinsics(spec), 1, i)
        nearest_target = (mesh.vertices @ R[i].T + t[i])[:, 2].min()
        for d in p.distractors:
            _, z = project(d.mesh.vertices * d.size, np.eye(3), d.R, d.t)
            assert 0.0 < z.min() and z.max() < nearest_target
            assert 0 <= d.mesh_index < len(pool_names(spec))


def test_placement_is_a_function_of_the_frame():
    spec = cluttered()
    mesh = load_instance(spec, 0)
    R, t = frames(spec, 2)
    K = spec_intrinsics(spec)
    a, b = (place_distractors(spec, mesh, R[0], t[0], K, 0, 0) for _ in range(2))
    c = place_distractors(spec, mesh, R[0], t[0], K, 0, 1)
    for x, y in zip(a.distractors, b.distractors):
        np.testing.assert_array_equal(x.t, y.t)
        assert x.mesh_index == y.mesh_index
    assert a.visible_target == b.visible_target != c.visible_target


def test_a_target_out_of_view_gets_no_distractors():
    spec = cluttered()
    mesh = load_instance(spec, 0)
    p = place_distractors(spec, mesh, np.eye(3), np.array([5.0, 0.0, 1.0]), spec_intrinsics(spec), 0, 0)
    assert p.distractors == () and p.visible == 1.0 and not p.amodal.any()


def test_the_root_search_finds_a_step_functions_crossing():
    steps = []

    def g(s):
        steps.append(s)
        return int(np.floor(1000 * (0.37 - s)))  # a pixel count: integer, decreasing

    s = _solve(g, tol=2)
    assert abs(g(s)) <= 2 and len(steps) < 20


def test_pool_names_list_classes_then_files(tmp_path):
    (tmp_path / "meshes").mkdir()
    import trimesh

    trimesh.creation.icosphere().export(tmp_path / "meshes" / "rock.obj")
    (tmp_path / "s.toml").write_text('class = "cup"\n[distractors]\ncount = 1\nclasses = ["box"]\ninstances = 2\n'
                                     'files = ["meshes/*.obj"]\n')
    from spm_data.core.specs import load_spec

    names = pool_names(load_spec(tmp_path / "s.toml"))
    assert names[:2] == ["box-10000", "box-10001"] and names[2].endswith("rock.obj")


@pytest.mark.parametrize("body, message", [
    ("count = 1\nvisible = [0.9, 0.1]", "distractors.visible"),
    ("count = 1\nvisible = [0.1, 1.2]", "distractors.visible"),
    ("count = -1", "distractors.count"),
    ("count = 1\nclasses = [\"boat\"]", "distractors.classes: 'boat'"),
    ("count = 1\nfiles = [\"none/*.obj\"]", "distractors.files: 'none/\\*.obj' matches no file"),
    ("count = 1\nscale = [0.0, 1.0]", "distractors.scale"),
    ("count = 1\nsize = 2", "distractors.size: unknown key"),
])
def test_bad_values_name_their_key(body, message):
    with pytest.raises(SpecError, match=message):
        parse_spec(f'class = "cup"\n[distractors]\n{body}\n')


def test_workbench_cannot_tell_distractors_apart():
    with pytest.raises(SpecError, match="distractors.count: Blender's Workbench has no object index pass"):
        parse_spec('class = "cup"\n[render.blender]\nengine = "workbench"\n[distractors]\ncount = 1\n')
    with pytest.raises(SpecError, match="outputs.instances: Blender's Workbench"):
        parse_spec('class = "cup"\n[render.blender]\nengine = "workbench"\n[outputs]\ninstances = true\n')
    parse_spec('class = "cup"\n[render]\nrenderer = "pyrender"\n[render.blender]\nengine = "workbench"\n'
               '[distractors]\ncount = 1\n')  # Workbench settings unused by pyrender


def test_a_renderer_override_is_checked_too(tmp_path):
    from spm_data.pipelines.render_jobs import load_run_specs

    (tmp_path / "c.toml").write_text('class = "cup"\n[render]\nrenderer = "pyrender"\n[render.blender]\n'
                                     'engine = "workbench"\n[distractors]\ncount = 1\n')
    assert load_run_specs(spec_files=[tmp_path / "c.toml"])[0].distractors.count == 1
    with pytest.raises(SpecError, match="cup with --renderer blender: distractors.count: Blender's Workbench"):
        load_run_specs(spec_files=[tmp_path / "c.toml"], renderer="blender")


def test_distractors_stay_beyond_the_renderers_near_clip_plane():
    from spm_data.core.raster import CLIP_NEAR

    spec = parse_spec('class = "cup"\n[camera]\nsampler = "sphere"\nviews = 12\ndistance_range = [0.3, 0.35]\n'
                      '[distractors]\ncount = 2\ndepth = [0.05, 0.1]\nscale = [1.0, 2.0]\nvisible = [0.2, 0.6]\n')
    mesh = load_instance(spec, 0)
    R, t = camera_path(spec.camera, spec.seed).poses(slice(0, 12))
    for i in range(12):
        p = place_distractors(spec, mesh, R[i], t[i], spec_intrinsics(spec), 0, i)
        for d in p.distractors:
            _, z = project(d.mesh.vertices * d.size, np.eye(3), d.R, d.t)
            assert z.min() >= 2 * CLIP_NEAR - 1e-9
        assert abs(p.visible - p.visible_target) <= 0.01


def test_a_target_too_near_the_camera_for_distractors_is_one_line():
    spec = cluttered()
    mesh = load_instance(spec, 0)
    with pytest.raises(SpmError, match="frame 0/3: the target comes within .* cm of the camera"):
        place_distractors(spec, mesh, np.eye(3), np.array([0.0, 0.0, 0.05]), spec_intrinsics(spec), 0, 3)


def test_specs_alike_in_text_keep_their_own_folders_files(tmp_path):
    import trimesh

    from spm_data.core.specs import load_spec

    text = 'class = "cup"\n[distractors]\ncount = 1\nfiles = ["m/*.obj"]\n'
    for name, mesh in (("a", trimesh.creation.box()), ("b", trimesh.creation.icosphere())):
        (tmp_path / name / "m").mkdir(parents=True)
        mesh.export(tmp_path / name / "m" / f"{name}.obj")
        (tmp_path / name / "s.toml").write_text(text)
    a, b = load_spec(tmp_path / "a" / "s.toml"), load_spec(tmp_path / "b" / "s.toml")
    assert a == b  # the same text: equal specs, yet other folders
    assert pool_names(a)[0].endswith("a.obj") and pool_names(b)[0].endswith("b.obj")
    from spm_data.core.distractors import pool_mesh

    assert len(pool_mesh(a, 0).faces) != len(pool_mesh(b, 0).faces)
