"""spm_data.pipelines.info: what ``spm-data info`` prints for a shard and for a folder."""

import numpy as np
import pytest

from spm_data.pipelines.info import info_text
from spm_data.errors import ShardError
from spm_data.io.shards import write_manifest, write_shard
from tests.helpers import make_arrays


@pytest.fixture
def folder(tmp_path):
    """One shard of 3 frames (8 x 10 pixels) with known labels, and its manifest."""
    a = make_arrays(n=3, h=8, w=10)
    a.update(class_name=["cup", "cup", "box"], instance_name=["cup/0", "cup/1", "box/0"], source=["synthetic"] * 3,
             azimuth=np.array([0.0, 5, 10]), elevation=np.array([20.0, 20, 25]), distance=np.array([0.6, 0.7, 0.6]),
             occlusion_fraction=np.array([0, 0.25, 0.5], np.float32))
    out = tmp_path / "shards"
    out.mkdir()
    write_shard(out / "cup-00000.h5", a, {"renderer": "pyrender", "seed": 3, "renderer_version": "pyrender 0.1.45"})
    write_manifest(out)
    return out


def test_a_shard_its_fields_classes_and_label_ranges(folder):
    lines = info_text(folder / "cup-00000.h5").splitlines()
    assert lines[:4] == [f"shard {folder / 'cup-00000.h5'}",
                         "  schema v3, 3 frames, 10x8, renderer pyrender (pyrender 0.1.45), seed 3",
                         "  rgb                  (3, 8, 10, 3)          uint8",
                         "  depth                (3, 8, 10)             float32"]
    assert "  class_name           (3,)                   str" in lines
    assert "  occlusion_rects      (3, 1, 4)              int32" in lines
    assert lines[-7:] == ["  classes: box (1), cup (2)", "  instances: box/0, cup/0, cup/1", "  sources: synthetic",
                          "  azimuth: 0..10 deg", "  elevation: 20..25 deg", "  distance: 0.6..0.7 m",
                          "  occlusion_fraction: 0..0.5"]
    assert len(lines) == 2 + 20 + 7                    # the header, the 20 fields, the labels


def test_a_folder_its_manifest_and_shards(folder):
    lines = info_text(folder).splitlines()
    size = (folder / "cup-00000.h5").stat().st_size / 1e6
    assert lines == [f"folder {folder}: 1 shards", "  manifest: 3 frames in 1 shards",
                     "    box                      1 frames", "    cup                      2 frames",
                     f"  cup-00000.h5                      3 frames  {size:8.2f} MB  pyrender", "  total: 3 frames"]


def test_a_folder_without_manifest_is_described_with_its_gaps(folder):
    (folder / "manifest.json").unlink()
    lines = info_text(folder).splitlines()
    assert lines[0] == f"folder {folder}: 1 shards"
    assert lines[1].startswith(f"  note: {folder}: no manifest.json; reading the 1 complete shards on disk")
    assert lines[2] == "  no manifest.json (an interrupted or foreign folder?)" and lines[-1] == "  total: 3 frames"


def test_nothing_there(tmp_path):
    with pytest.raises(ShardError, match="^no such shard or folder: "):
        info_text(tmp_path / "nothing")


def test_a_shard_rendered_by_cycles_says_on_which_device(tmp_path):
    a = make_arrays(n=1, h=4, w=4)
    write_shard(tmp_path / "b.h5", a, {"renderer": "blender", "seed": 0, "renderer_version": "Blender 5.0.1",
                                       "renderer_settings": '{"device": "OPTIX", "samples": 16}'})
    assert info_text(tmp_path / "b.h5").splitlines()[1] == ("  schema v3, 1 frames, 4x4, renderer blender "
                                                           "(Blender 5.0.1, on OPTIX), seed 0")
