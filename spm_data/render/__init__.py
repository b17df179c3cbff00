"""The renderers, one registration each: :data:`RENDERERS` maps a spec's ``render.renderer`` name
to its backend. Specs (the names, the ``[render.<name>]`` settings table and its checks), the
``--renderer`` choices, :func:`make_renderer` and the layers test all read this one table.

To add a renderer ``vk``: write ``spm_data/render/vk.py`` with a Renderer subclass
(spm_data/render/base.py); if it has settings, a frozen dataclass and a ``check(spec)`` in
``spm_data/render/vk_settings.py`` (as blender_settings.py); then one entry below.

This module and the settings modules import no Blender, OpenGL or core module: core/specs.py
reads them. The backends are imported only when a renderer is built.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Callable

from spm_data.errors import RenderError
from spm_data.render.blender_settings import BlenderSettings, check_blender


@dataclass(frozen=True)
class Backend:
    module: str                       # the backend module, imported when a renderer is built
    cls: str                          # its Renderer subclass
    settings: type | None = None      # frozen dataclass of the spec's [render.<name>] table, or None
    check: Callable | None = None     # check(spec): SpecError for bad settings (run on every spec)
    in_process: bool = False          # may render in the calling process when there is one local worker


RENDERERS: dict[str, Backend] = {
    "pyrender": Backend("spm_data.render.pyrender_backend", "PyrenderRenderer", in_process=True),
    "blender": Backend("spm_data.render.blender", "BlenderRenderer", BlenderSettings, check_blender),
}


def renderer_names() -> tuple[str, ...]:
    """The registered renderer names, in registration order."""
    return tuple(RENDERERS)


def make_renderer(spec, name: str | None = None):
    """Build the renderer ``name`` (default: the spec's) for ``spec``: a spm_data.render.base.Renderer."""
    name = name or spec.render.renderer
    if name not in RENDERERS:
        raise RenderError(f"unknown renderer {name!r}; expected one of {', '.join(RENDERERS)}")
    backend = RENDERERS[name]
    return getattr(importlib.import_module(backend.module), backend.cls)(spec)
