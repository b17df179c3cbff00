"""The Blender backend's settings: the spec's ``[render.blender]`` table and its checks, kept
apart from spm_data/render/blender.py so specs can read them without Blender's own layer."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from spm_data.errors import SpecError

ENGINES = ("cycles", "workbench", "eevee")
DEVICES = ("cpu", "gpu", "auto")


@dataclass(frozen=True)
class BlenderSettings:
    engine: str = "cycles"          # "cycles" | "workbench"
    samples: int = 16
    denoise: bool = False
    film_transparent: bool = True
    threads: int = 0                # 0: Blender's default (all cores)
    device: str = "cpu"             # Cycles: "cpu" | "gpu" | "auto" (a GPU if Blender finds one, else the CPU)

    # Keys added after specs were fingerprinted: at these values a spec keeps its old fingerprint.
    FINGERPRINT_SKIPS: ClassVar[dict] = {"device": "cpu"}


def _check(ok: bool, message: str) -> None:
    if not ok:
        raise SpecError(message)


def check_blender(spec) -> None:
    """SpecError naming the key when ``spec.render.blender`` has a bad value, or when the spec asks
    Blender's Workbench engine for what it cannot draw (random lights, distractors, instance ids,
    normals). Every spec's table is checked, whichever renderer it names."""
    b = spec.render.blender
    _check(b.engine in ENGINES, f"render.blender.engine: expected cycles or workbench, got {b.engine!r}")
    _check(1 <= b.samples <= 65536, f"render.blender.samples: expected 1..65536, got {b.samples}")
    _check(b.threads >= 0, f"render.blender.threads: expected >= 0, got {b.threads}")
    _check(b.device in DEVICES, f"render.blender.device: expected one of {', '.join(DEVICES)}, got {b.device!r}")
    if not (spec.render.renderer == "blender" and b.engine == "workbench"):
        return
    lit = [k for k in ("lights", "light_strength", "light_color", "ambient", "base_color", "roughness", "metallic")
           if getattr(spec.randomize, k)]
    _check(not lit, f"randomize.{lit[0] if lit else ''}: Workbench lights with its own studio light and no "
                    "materials; use engine = \"cycles\" or the pyrender renderer")
    _check(not (spec.distractors.count or spec.outputs.instances),
           f"{'distractors.count' if spec.distractors.count else 'outputs.instances'}: Blender's Workbench has no "
           "object index pass to tell the objects apart; use engine = \"cycles\" or the pyrender renderer")
    _check(not spec.outputs.normals,
           "outputs.normals: Blender's Workbench has no normal pass; use engine = \"cycles\" or the pyrender renderer")
