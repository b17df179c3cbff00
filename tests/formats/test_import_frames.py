"""spm_data.formats.import_frames: frames streamed to the shard a block at a time (progress
counts stored frames), a frame that fails part way restarts the shard without it, and --max-side
scales K exactly with the image."""

import numpy as np
import pytest

from spm_data.core.poses import K_to_corner_origin, project_points, scale_K
from spm_data.formats import import_frames
from spm_data.formats.nerf import import_nerf
from spm_data.io.shards import list_shards, read_attrs, read_shard
from tests.helpers import CENTER, SCALE, write_capture


def _capture(root, n=11, h=40, w=60):
    """``n`` frames of a bright rectangle (alpha = mask) seen by cameras 0.6 m away."""
    from spm_data.core.poses import camera_pose, intrinsics_from_fov

    rgb = np.zeros((n, h, w, 3), np.uint8)
    rgb[:, 10:30, 20:45] = (200, 150, 90)
    mask = rgb.max(axis=3) > 0
    K = np.stack([intrinsics_from_fov(40.0, w, h)] * n)
    poses = [camera_pose(10.0 * i, 15.0, 0.0, 0.6) for i in range(n)]
    return write_capture(root, rgb, mask, K, np.stack([p[0] for p in poses]), np.stack([p[1] for p in poses]))


def test_a_frame_that_fails_in_a_later_block_restarts_the_shard_without_it(tmp_path, monkeypatch):
    capture = _capture(tmp_path / "c")
    broken = capture / "images" / "frame_00009.png"
    broken.write_bytes(broken.read_bytes()[:60])          # its header reads, its pixels do not
    monkeypatch.setattr(import_frames, "BLOCK", 4)
    deltas = []

    class Count:
        total = None

        def __call__(self, n=1):
            deltas.append(n)

    summary, problems = import_nerf(capture, tmp_path / "out", scale=SCALE, center=CENTER, progress=Count())
    assert problems == [] and summary.frames == 10
    skipped = [s for r in summary.results.values() for s in r["skipped"]]
    assert [s[0] for s in skipped] == [str(broken)]
    assert deltas == [4, 1 - 4, 4, 4, 2]   # stored one block behind; the skipped counted, the 4 stored taken back
    shard = list_shards(tmp_path / "out")[0]
    d = read_shard(shard, ["source_shard", "mask"])
    assert str(broken) not in set(d["source_shard"]) and len(d["mask"]) == 10 == read_attrs(shard)["frames"]


def test_max_side_scales_k_exactly_with_the_image(tmp_path):
    capture = _capture(tmp_path / "c", n=3, h=40, w=60)
    import_nerf(capture, tmp_path / "full", scale=SCALE, center=CENTER)
    import_nerf(capture, tmp_path / "half", scale=SCALE, center=CENTER, max_side=30)
    full, half = (read_shard(list_shards(tmp_path / k)[0]) for k in ("full", "half"))
    assert half["rgb"].shape == (3, 20, 30, 3) and full["rgb"].shape == (3, 40, 60, 3)
    np.testing.assert_allclose(half["K"], np.stack([scale_K(K, 0.5, 0.5) for K in full["K"]]), atol=1e-12)
    # The same point projects to the same place of the picture: pixel corners map to corners.
    point = np.array([[0.01, -0.02, 0.03]])
    uv_full, _ = project_points(point, full["K"][0], full["R"][0], full["t"][0])
    uv_half, _ = project_points(point, half["K"][0], half["R"][0], half["t"][0])
    np.testing.assert_allclose((uv_half + 0.5) / (30, 20), (uv_full + 0.5) / (60, 40), atol=1e-12)
    np.testing.assert_allclose(K_to_corner_origin(half["K"][0])[:2, 2], K_to_corner_origin(full["K"][0])[:2, 2] / 2)
    assert (half["mask"][0] == full["mask"][0][::2, ::2]).all()


def test_scale_k_maps_the_image_extent_onto_the_new_one():
    K = np.array([[100.0, 0.0, 31.5], [0.0, 90.0, 19.5], [0.0, 0.0, 1.0]])   # a centred 64 x 40 camera
    S = scale_K(K, 0.25, 0.5)
    assert S[0, 0] == 25.0 and S[1, 1] == 45.0
    assert S[0, 2] == pytest.approx((16 - 1) / 2) and S[1, 2] == pytest.approx((20 - 1) / 2)   # still centred


def test_a_capture_without_depth_has_no_depth_field_and_reads_as_zero_depth(tmp_path):
    """No depth array is written for a capture without depth; validate accepts the shard, a read of
    depth gives zeros (no surface measured: N3M and SIFT + PnP decline it as before), and a merge
    with renders keeps their depth."""
    from spm_data.pipelines.merge import merge_folders
    from spm_data.pipelines.validate import validate_folder
    from spm_data.io.shards import shard_layout

    import_nerf(_capture(tmp_path / "c", n=3), tmp_path / "out", scale=SCALE, center=CENTER)
    shard = list_shards(tmp_path / "out")[0]
    assert "depth" not in shard_layout(shard) and validate_folder(tmp_path / "out") == []
    depth = read_shard(shard, ["depth"], frames=slice(1, 3))["depth"]
    assert depth.shape == (2, 40, 60) and depth.dtype == np.float32 and not depth.any()
    assert read_shard(shard, ["depth"], frames=2)["depth"].shape == (40, 60)
    merge_folders([tmp_path / "out"], tmp_path / "merged")
    assert not read_shard(list_shards(tmp_path / "merged")[0], ["depth"])["depth"].any()


def test_a_shard_whose_every_frame_is_skipped_is_not_missing(tmp_path):
    """Shards of 2 frames; both frames of the second fail as they are read: that shard is not
    written and not listed as missing, so validate (tests/conftest.py) accepts the folder."""
    capture = _capture(tmp_path / "c", n=6)
    for i in (2, 3):
        path = capture / "images" / f"frame_{i:05d}.png"
        path.write_bytes(path.read_bytes()[:60])
    summary, _ = import_nerf(capture, tmp_path / "out", scale=SCALE, center=CENTER, frames_per_shard=2)
    from spm_data.io.shards import read_manifest

    manifest = read_manifest(tmp_path / "out")
    assert summary.frames == 4 and [e["file"] for e in manifest["shards"]] == ["nerf-00000.h5", "nerf-00002.h5"]
    assert not manifest.get("missing")
