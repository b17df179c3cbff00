"""spm_data.render: the registry of renderers, and make_renderer, which builds the registered
backend a spec names; specs read the registry's names, settings tables and checks."""

import subprocess
import sys

import numpy as np
import pytest

from spm_data.core.specs import RenderSettings, parse_spec
from spm_data.errors import RenderError
from spm_data.render import RENDERERS, make_renderer, renderer_names
from spm_data.render.base import Renderer, spec_intrinsics
from spm_data.render.blender_settings import BlenderSettings

SPEC = 'class = "cup"\n[image]\nwidth = 64\nheight = 48\nfov = 40\n[render]\nrenderer = "pyrender"\n'


def test_make_renderer_builds_the_named_backend_and_refuses_others():
    spec = parse_spec(SPEC)
    with pytest.raises(RenderError, match=r"^unknown renderer 'vulkan'; expected one of pyrender, blender$"):
        make_renderer(spec, "vulkan")
    with make_renderer(spec) as renderer:
        assert isinstance(renderer, Renderer) and renderer.name == "pyrender"
        assert (renderer.width, renderer.height) == (64, 48)
        np.testing.assert_array_equal(renderer.K, spec_intrinsics(spec))


def test_the_registry_names_each_backend_with_its_settings():
    assert renderer_names() == ("pyrender", "blender")
    assert RENDERERS["blender"].settings is BlenderSettings and RENDERERS["pyrender"].settings is None
    assert RENDERERS["pyrender"].in_process and not RENDERERS["blender"].in_process
    # the spec's [render] table has one settings table per renderer that has settings
    assert parse_spec(SPEC).render.blender == BlenderSettings()
    assert not hasattr(RenderSettings(), "pyrender")


VK = """
import dataclasses
from spm_data.errors import SpecError
import spm_data.render as render

@dataclasses.dataclass(frozen=True)
class VkSettings:
    queues: int = 1

def check(spec):
    if spec.render.vk.queues < 1:
        raise SpecError(f"render.vk.queues: expected >= 1, got {spec.render.vk.queues}")

render.RENDERERS["vk"] = render.Backend("no.such.module", "Vk", VkSettings, check)
from spm_data.core.specs import parse_spec
spec = parse_spec('class = "cup"\\n[render]\\nrenderer = "vk"\\n[render.vk]\\nqueues = 3\\n')
print(spec.render.vk.queues, spec.render.blender.samples)
for text in ('class = "cup"\\n[render.vk]\\nqueues = 0\\n', 'class = "cup"\\n[render]\\nrenderer = "gl"\\n'):
    try:
        parse_spec(text)
    except SpecError as exc:
        print(exc)
"""


def test_one_registration_makes_a_renderer_a_spec_knows():
    """An entry added to RENDERERS before specs load is a renderer name, a [render.NAME] table and a check."""
    r = subprocess.run([sys.executable, "-c", VK], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines() == ["3 16", "<spec>: render.vk.queues: expected >= 1, got 0",
                                     "<spec>: render.renderer: expected one of pyrender, blender, vk, got 'gl'"]
