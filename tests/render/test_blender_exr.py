import numpy as np
import pytest

from spm_data.errors import RenderError
from spm_data.render.blender_exr import import_openexr, read_frame

OpenEXR = pytest.importorskip("OpenEXR")


def _write_exr(path, h, w, with_index=True, with_normals=False):
    """A multi-layer EXR as Blender 5 writes one: a 2x3 block of the target at rows 1-2, columns 1-3."""
    rgba = np.zeros((h, w, 4), np.float32)
    rgba[1:3, 1:4] = [0.5, 0.2, 1.0, 1.0]
    z = np.full((h, w), 1e10, np.float32)
    z[1:3, 1:4] = 0.7
    z[0, 0] = 1.5                           # a distractor
    index = np.zeros((h, w), np.float32)
    index[1:3, 1:4] = 1
    index[0, 0] = 2
    channels = {f"ViewLayer.Combined.{c}": np.ascontiguousarray(rgba[..., i]) for i, c in enumerate("RGBA")}
    channels["ViewLayer.Depth.Z"] = z
    if with_index:
        channels["ViewLayer.Object Index.X"] = index
    if with_normals:
        for i, c in enumerate("XYZ"):
            channels[f"ViewLayer.Normal.{c}"] = np.full((h, w), float(i == 2), np.float32)
    header = {"compression": OpenEXR.NO_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, channels) as f:
        f.write(str(path))


def test_a_full_frame_reads_as_the_renderer_arrays(tmp_path):
    _write_exr(tmp_path / "f.exr", 4, 5, with_normals=True)
    out = read_frame(import_openexr(), str(tmp_path / "f.exr"), normals=True, distractor_slots=False,
                     crop=None, height=4, width=5)
    assert out["mask"].sum() == 6 and out["mask"][1:3, 1:4].all()
    np.testing.assert_array_equal(out["ids"][0, 0], 2)
    assert out["depth"][0, 0] == 0.0 and out["depth"][1, 1] == np.float32(0.7)   # the target's depth only
    np.testing.assert_array_equal(out["rgb"][1, 1], [188, 124, 255])               # sRGB of 0.5, 0.2, 1.0
    np.testing.assert_array_equal(out["world_normals"][2, 2], [0, 0, 1])
    with_slots = read_frame(import_openexr(), str(tmp_path / "f.exr"), normals=False, distractor_slots=True,
                            crop=None, height=4, width=5)
    assert with_slots["depth"][0, 0] == np.float32(1.5) and "world_normals" not in with_slots


def test_a_render_border_is_put_back_in_a_full_frame(tmp_path):
    _write_exr(tmp_path / "b.exr", 4, 5)
    out = read_frame(import_openexr(), str(tmp_path / "b.exr"), normals=False, distractor_slots=False,
                     crop=(2, 3, 7, 7), height=10, width=12)
    assert out["mask"].shape == (10, 12) and out["mask"].sum() == 6 and out["mask"][4:6, 3:6].all()
    with pytest.raises(RenderError, match="Blender's EXR is 5x4, expected 12x10 or its render border 4x4"):
        read_frame(import_openexr(), str(tmp_path / "b.exr"), normals=False, distractor_slots=False,
                   crop=(2, 3, 6, 7), height=10, width=12)


def test_a_missing_pass_or_file_is_one_render_error(tmp_path):
    _write_exr(tmp_path / "n.exr", 4, 5)
    with pytest.raises(RenderError, match="could not read Blender's EXR output .KeyError"):
        read_frame(import_openexr(), str(tmp_path / "n.exr"), normals=True, distractor_slots=False,
                   crop=None, height=4, width=5)
    with pytest.raises(RenderError, match="could not read Blender's EXR output"):
        read_frame(import_openexr(), str(tmp_path / "missing.exr"), normals=False, distractor_slots=False,
                   crop=None, height=4, width=5)
    _write_exr(tmp_path / "i.exr", 4, 5, with_index=False)   # no index pass: every hit is the target
    out = read_frame(import_openexr(), str(tmp_path / "i.exr"), normals=False, distractor_slots=False,
                     crop=None, height=4, width=5)
    assert out["mask"].sum() == 7
