"""spm_data.render.base: the Renderer interface and what the backends share (intrinsics from the
spec, lights around the camera, masks from depth)."""

import re

import numpy as np
import pytest

from spm_data.core.poses import intrinsics_from_fov
from spm_data.core.specs import parse_spec
from spm_data.errors import RenderError
from spm_data.render.base import Renderer, labels_agreeing_with_depth, light_rotations, mask_from_depth, spec_intrinsics

SPEC = 'class = "cup"\n[image]\nwidth = 64\nheight = 48\nfov = 40\n[render]\nrenderer = "pyrender"\n'


def test_spec_intrinsics_are_the_specs_field_of_view_at_pixel_centres():
    spec = parse_spec(SPEC)
    K = spec_intrinsics(spec)
    np.testing.assert_array_equal(K, intrinsics_from_fov(40, 64, 48))
    assert (K[0, 2], K[1, 2]) == (31.5, 23.5) and K.dtype == np.float64


def test_a_renderer_must_implement_the_interface_and_closes_as_a_context_manager():
    class Half(Renderer):
        def version(self):
            return "half 0"

    with pytest.raises(TypeError, match="abstract"):
        Half(parse_spec(SPEC))

    class Null(Half):
        closed = 0

        def settings(self):
            return {}

        def set_mesh(self, mesh):
            pass

        def render(self, R, t):
            return {}

        def close(self):
            Null.closed += 1

    with Null(parse_spec(SPEC)) as r:
        assert r.K.shape == (3, 3)
    assert Null.closed == 1


def test_lights_are_a_head_light_and_a_40_degree_cone_around_it():
    assert len(light_rotations(0)) == 0
    (head,) = light_rotations(1)
    np.testing.assert_array_equal(head, np.eye(3))
    rots = light_rotations(4)
    np.testing.assert_array_equal(rots[0], np.eye(3))
    for R in rots:
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)
    directions = np.array([R @ [0, 0, 1.0] for R in rots[1:]])
    np.testing.assert_allclose(np.degrees(np.arccos(directions[:, 2])), 40.0)          # 40 degrees off the axis
    azimuths = np.degrees(np.arctan2(directions[:, 1], directions[:, 0])) % 360
    np.testing.assert_allclose(np.sort(np.diff(np.sort(azimuths))), [120.0, 120.0])    # spread evenly around it


def test_mask_from_depth():
    depth = np.array([[0.0, 0.5], [1e-9, -0.0]], np.float32)
    mask = mask_from_depth(depth)
    assert mask.dtype == np.uint8 and mask.tolist() == [[0, 1], [1, 0]]


def test_labels_follow_the_colour_pass_where_the_label_pass_disagrees():
    depth = np.array([[0.5, 0.5, 0.9, 0.0],
                      [0.5, 0.7, 0.9, 0.9],
                      [0.0, 0.0, 0.9, 0.0]], np.float32)
    label_depth = depth.copy()
    labels = np.array([[1, 1, 2, 0],
                       [1, 0, 2, 2],
                       [0, 3, 2, 0]], np.uint8)
    agreeing = np.where(depth > 0, labels, 0)
    agreeing[1, 1] = 1
    np.testing.assert_array_equal(labels_agreeing_with_depth(agreeing, depth, depth), agreeing)   # nothing to do
    label_depth[1, 1] = 0.0            # the label pass missed a pixel the colour pass drew (Mesa, 1 px)
    label_depth[0, 2] = 0.55           # ... and drew another surface at one pixel
    labels[0, 2] = 1
    label_depth[2, 1] = 0.3            # drew where the colour pass has nothing: no label there
    out = labels_agreeing_with_depth(labels, depth, label_depth)
    assert out.dtype == np.uint8
    assert out.tolist() == [[1, 1, 2, 0],  # [0, 2]: its kept neighbours nearest 0.9 are label 2
                            [1, 1, 2, 2],  # [1, 1] at 0.7: neighbour 0.5 (label 1) is nearer than 0.9 (2)
                            [0, 0, 2, 0]]


# --------------------------------------------------------------------------- GPUs

def test_gpus_are_parsed_and_bad_syntax_is_one_line():
    from spm_data.errors import RenderError
    from spm_data.render.base import parse_gpus

    assert parse_gpus(None) is None and parse_gpus("0") == (0,) and parse_gpus(" 0, 1,3 ") == (0, 1, 3)
    for text in ("", "a", "0,,1", "-1", "1.5", "0;1", "²"):
        with pytest.raises(RenderError, match=r"^--gpus .*: expected GPU indices separated by commas, such as 0 or "
                                              r"0,1,3$"):
            parse_gpus(text)
    with pytest.raises(RenderError, match=r"^--gpus '1,0,1': GPU 1 is named twice$"):
        parse_gpus("1,0,1")


def test_the_gpus_chosen_are_those_wanted_out_of_those_listed():
    from spm_data.errors import RenderError
    from spm_data.render.base import choose_gpus

    assert choose_gpus(None, (0, 1, 2)) == (0, 1, 2)                 # default: every GPU listed
    assert choose_gpus(None, ()) == ()                               # none: the CPU
    assert choose_gpus((2, 0), (0, 1, 2)) == (2, 0)
    with pytest.raises(RenderError, match=r"^--gpus 0: no GPU here \(pyrender's EGL lists none\); leave --gpus out "
                                          r"to render on the CPU$"):
        choose_gpus((0,), (), "pyrender's EGL")
    with pytest.raises(RenderError, match=r"^--gpus 1,4: there is no GPU 4; EGL lists 2: 0, 1$"):
        choose_gpus((1, 4), (0, 1), "EGL")


@pytest.mark.parametrize("workers, gpus, processes", [(1, 0, 1), (8, 0, 8), (8, 1, 4), (16, 2, 8), (8, 4, 8),
                                                      (3, 2, 3), (1, 4, 1)])
def test_gl_processes_are_one_per_worker_on_the_cpu_and_few_per_gpu(workers, gpus, processes):
    from spm_data.render.base import CONTEXTS_PER_GPU, gl_processes

    assert CONTEXTS_PER_GPU == 4 and gl_processes(workers, gpus) == processes


def test_a_worker_reads_its_gpu_and_blender_lists_its_gpus_only_in_its_workers():
    from spm_data.render.base import GPU_VARIABLE, assigned_gpu, visible_gpus

    assert assigned_gpu({}) is None and assigned_gpu({GPU_VARIABLE: "3"}) == 3
    assert assigned_gpu({GPU_VARIABLE: ""}) is None
    assert visible_gpus("blender") is None
    gpus, lister = visible_gpus("pyrender")
    assert lister == "pyrender's EGL" and all(isinstance(g, int) for g in gpus)


def test_contexts_per_gpu_is_the_users_own_when_set_and_refused_in_one_line_when_wrong(monkeypatch):
    from spm_data.render.base import CONTEXTS_PER_GPU, contexts_per_gpu, gl_processes

    assert contexts_per_gpu({}) == CONTEXTS_PER_GPU == contexts_per_gpu({"SPM_CONTEXTS_PER_GPU": " "})
    assert contexts_per_gpu({"SPM_CONTEXTS_PER_GPU": "8"}) == 8
    monkeypatch.setenv("SPM_CONTEXTS_PER_GPU", "2")
    assert gl_processes(8, 1) == 2 and gl_processes(8, 0) == 8 and gl_processes(8, 1, per_gpu=3) == 3
    for bad in ("0", "65", "-1", "two", "1.5"):
        with pytest.raises(RenderError, match=rf"^SPM_CONTEXTS_PER_GPU='{re.escape(bad)}': expected a whole number "
                                              r"of GL contexts per GPU from 1 to 64; unset it for the default, 4$"):
            contexts_per_gpu({"SPM_CONTEXTS_PER_GPU": bad})
