"""BOP models: texture colours, symmetry entries, evaluation resampling, models_info."""

import numpy as np
import pytest
import trimesh

from spm_data.core.meshes import diameter
from spm_data.formats.bop.models import (diameter_ends, eval_resample, extreme_vertices, load_models_info, model_info,
                                         save_bop_model, save_models_info, symmetry_info, texture_colors)
from spm_data.formats.ply import load_ply
from spm_data.core.symmetries import NO_SYMMETRY, Symmetries, rotation


def test_texture_colors_take_the_pixel_at_uv_with_v_up():
    texture = np.zeros((2, 3, 3), np.uint8)
    texture[0, 0] = (255, 0, 0)   # top-left: u = 0, v = 1
    texture[1, 2] = (0, 0, 255)   # bottom-right: u = 1, v = 0
    colors = texture_colors(texture, np.array([[0.0, 1.0], [1.0, 0.0], [0.0, 0.0]]))
    np.testing.assert_array_equal(colors, [[255, 0, 0], [0, 0, 255], [0, 0, 0]])


def test_symmetry_entries_in_bop_layout():
    info = symmetry_info(Symmetries(discrete=(rotation([0, 0, 1], 180),), continuous=(np.array([0, 0, 1.0]),)))
    assert info["symmetries_discrete"] == [[-1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]]
    assert info["symmetries_continuous"] == [{"axis": [0.0, 0.0, 1.0], "offset": [0.0, 0.0, 0.0]}]
    assert symmetry_info(NO_SYMMETRY) == {}   # omitted when there are none


def test_model_info_and_diameter(tmp_path):
    box = trimesh.creation.box(extents=(30.0, 40.0, 120.0))
    assert diameter(box.vertices) == np.sqrt(30 ** 2 + 40 ** 2 + 120 ** 2)   # 130, exactly
    info = model_info(box.vertices, NO_SYMMETRY)
    assert (info["min_x"], info["size_y"], info["size_z"], info["diameter"]) == (-15.0, 40.0, 120.0, 130.0)
    save_models_info(tmp_path / "models_info.json", {1: info})
    assert load_models_info(tmp_path / "models_info.json") == {1: info}


def calc_model_info_numbers(points):
    """What calc_model_info.py computes from a PLY's vertices (its rules, written out here): box
    from the float32 values, diameter as the largest sqrt(dx² + dy² + dz²) over all pairs."""
    pts = np.asarray(points, dtype=np.float32).astype(np.float64)
    best = 0.0
    for i in range(len(pts)):
        d = pts[i] - pts[i:]
        best = max(best, float(np.sqrt((d * d).sum(axis=1).max())))
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    return {"diameter": best, "min_x": lo[0], "min_y": lo[1], "min_z": lo[2], "size_x": hi[0] - lo[0],
            "size_y": hi[1] - lo[1], "size_z": hi[2] - lo[2]}


def test_numbers_are_calc_model_info_s_from_the_float32_vertices():
    rng = np.random.default_rng(1)
    for points in (rng.normal(size=(700, 3)) * [80.0, 50.0, 20.0], trimesh.creation.icosphere(3).vertices * 125.3):
        pts = np.float64(np.float32(points))
        d, i, j = diameter_ends(pts)
        assert np.sqrt(((pts[i] - pts[j]) ** 2).sum()) == pytest.approx(d, rel=1e-15)
        info = model_info(points, NO_SYMMETRY)
        assert {k: info[k] for k in calc_model_info_numbers(points)} == calc_model_info_numbers(points)
    # Rounded to float32 first, as the PLY stores it: -124.99999999999999 is -125.0 there.
    assert model_info(np.array([[-124.99999999999999, 0, 0], [125.0, 1, 1]]), NO_SYMMETRY)["min_x"] == -125.0


def test_eval_models_keep_the_extreme_vertices_so_both_folders_have_the_same_numbers(tmp_path):
    from spm_data.core.shapes import procedural_mesh

    for sub in ("models", "models_eval"):
        (tmp_path / sub).mkdir()
    mesh = procedural_mesh("cup", 2)
    entry = save_bop_model(tmp_path, 7, mesh)
    render = load_ply(tmp_path / "models" / "obj_000007.ply")["vertices"]
    resampled = load_ply(tmp_path / "models_eval" / "obj_000007.ply")["vertices"]
    ends = extreme_vertices(np.float32(render))
    assert 2 <= len(ends) <= 8 and all((resampled == render[k]).all(axis=1).any() for k in ends)
    for sub in ("models", "models_eval"):
        save_models_info(tmp_path / sub / "models_info.json", {7: entry})
    a, b = (load_models_info(tmp_path / sub / "models_info.json")[7] for sub in ("models", "models_eval"))
    assert a == b == entry
    assert {k: a[k] for k in calc_model_info_numbers(resampled)} == calc_model_info_numbers(resampled)


def test_eval_resample_spreads_vertices_evenly():
    # A box with 8 corners: resampled, its faces are covered with vertices a cell apart.
    box = trimesh.creation.box(extents=(100.0, 100.0, 100.0))
    v, f, n = eval_resample(box.vertices, box.faces, 10.0)
    assert 500 < len(v) < 700   # 6 faces x about 10 x 10 cells
    np.testing.assert_allclose(np.abs(v).max(axis=0), 50.0, atol=1e-9)   # on the surface
    assert np.abs(v).max(axis=1).min() == 50.0   # every vertex a point of the surface
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-9)
    spacing = np.linalg.norm(v[f[:, 0]] - v[f[:, 1]], axis=1)
    assert spacing.max() < 25.0 and np.median(spacing) > 3.0   # neighbouring cells, at most 2.5 cells apart


def test_an_object_exported_twice_is_resampled_once_and_written_the_same(tmp_path, monkeypatch):
    from spm_data.core.shapes import procedural_mesh
    from spm_data.formats.bop import models as bop_models

    calls = []
    monkeypatch.setattr(bop_models, "_RESAMPLED", {})
    monkeypatch.setattr(bop_models, "eval_resample",
                        lambda *a: calls.append(1) or eval_resample(*a))
    mesh = procedural_mesh("box", 3)
    for out in ("a", "b"):
        for sub in ("models", "models_eval"):
            (tmp_path / out / sub).mkdir(parents=True)
        bop_models.save_bop_model(tmp_path / out, 1, mesh)
    assert len(calls) == 1
    assert (tmp_path / "a/models_eval/obj_000001.ply").read_bytes() == \
        (tmp_path / "b/models_eval/obj_000001.ply").read_bytes()
    # Another shape (or the same one moved) is resampled afresh.
    bop_models.save_bop_model(tmp_path / "a", 2, procedural_mesh("box", 4))
    assert len(calls) == 2


def test_row_keys_order_rows_as_unique_with_axis_0_does():
    from spm_data.formats.bop.models import _row_keys

    rows = np.random.default_rng(0).integers(-5, 6, size=(2000, 3))
    _, inverse = np.unique(_row_keys(rows), return_inverse=True)
    _, expected = np.unique(rows, axis=0, return_inverse=True)
    np.testing.assert_array_equal(inverse, expected.ravel())


def test_a_pool_mesh_drawn_at_several_sizes_is_resampled_once(tmp_path, monkeypatch):
    """Distractors: one mesh of the pool at its drawn sizes; the cell (a fraction of each model's
    float32 diameter over its size) differs in the last digits from size to size, and still
    names one resampling."""
    from spm_data.core.meshes import TexturedMesh
    from spm_data.core.shapes import procedural_mesh
    from spm_data.formats.bop import models as bop_models

    calls = []
    monkeypatch.setattr(bop_models, "_RESAMPLED", {})
    monkeypatch.setattr(bop_models, "eval_resample", lambda *a: calls.append(a[2]) or eval_resample(*a))
    unit = procedural_mesh("ball", 2)
    for sub in ("models", "models_eval"):
        (tmp_path / sub).mkdir()
    for obj_id, size in enumerate((0.0713, 0.0927, 0.1131, 0.0588), start=1):
        mesh = TexturedMesh(unit.name, unit.vertices * size, unit.faces, unit.normals, unit.uv, unit.texture,
                            unit.symmetries)
        info = bop_models.save_bop_model(tmp_path, obj_id, mesh, unit, size)
        assert info["diameter"] > 0
    assert len(calls) == 1
