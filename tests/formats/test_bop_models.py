"""BOP models: texture colours, symmetry entries, evaluation resampling, models_info."""

import numpy as np
import trimesh

from spm_data.core.meshes import diameter
from spm_data.formats.bop_models import (eval_resample, load_models_info, model_info, save_models_info,
                                         symmetry_info, texture_colors)
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
    from spm_data.formats import bop_models

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
    from spm_data.formats.bop_models import _row_keys

    rows = np.random.default_rng(0).integers(-5, 6, size=(2000, 3))
    _, inverse = np.unique(_row_keys(rows), return_inverse=True)
    _, expected = np.unique(rows, axis=0, return_inverse=True)
    np.testing.assert_array_equal(inverse, expected.ravel())
