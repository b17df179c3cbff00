"""spm_data.render.blender_settings: the [render.blender] table the Blender backend owns, its checks
(each bad value one SpecError naming the key), and what Workbench cannot draw, refused only when
the spec renders with Blender's Workbench."""

import pytest

from spm_data.core.specs import parse_spec
from spm_data.errors import SpecError
from spm_data.render.blender_settings import BlenderSettings, check_blender


def spec(blender="", renderer="blender", extra=""):
    return parse_spec(f'class = "cup"\n[render]\nrenderer = "{renderer}"\n[render.blender]\n{blender}\n{extra}')


def test_the_table_reads_into_the_backends_dataclass():
    s = spec('engine = "workbench"\nsamples = 4\ndevice = "auto"')
    assert s.render.blender == BlenderSettings(engine="workbench", samples=4, device="auto")
    check_blender(s)  # valid: no error


@pytest.mark.parametrize("line, message", [
    ('engine = "povray"', "render.blender.engine: expected cycles or workbench, got 'povray'"),
    ("samples = 0", "render.blender.samples: expected 1..65536, got 0"),
    ("threads = -1", "render.blender.threads: expected >= 0, got -1"),
    ('device = "tpu"', "render.blender.device: expected one of cpu, gpu, auto, got 'tpu'"),
])
def test_each_bad_value_names_its_key_whatever_the_renderer(line, message):
    for renderer in ("blender", "pyrender"):
        with pytest.raises(SpecError, match=f"^<spec>: {message}$"):
            spec(line, renderer)


@pytest.mark.parametrize("extra, key", [
    ("[randomize]\nlights = [1, 3]", "randomize.lights: Workbench lights with its own studio light"),
    ("[distractors]\ncount = 1", "distractors.count: Blender's Workbench has no object index pass"),
    ("[outputs]\ninstances = true", "outputs.instances: Blender's Workbench has no object index pass"),
    ("[outputs]\nnormals = true", "outputs.normals: Blender's Workbench has no normal pass"),
])
def test_workbench_refuses_what_it_cannot_draw_only_when_it_renders(extra, key):
    with pytest.raises(SpecError, match=f"^<spec>: {key}"):
        spec('engine = "workbench"', extra=extra)
    spec('engine = "cycles"', extra=extra)
    spec('engine = "workbench"', "pyrender", extra=extra)


def test_a_cpu_device_keeps_the_fingerprint_specs_had_before_the_key():
    assert BlenderSettings.FINGERPRINT_SKIPS == {"device": "cpu"}
    assert spec('device = "cpu"').fingerprint() == spec("").fingerprint() != spec('device = "gpu"').fingerprint()
