"""Blender worker memory over a long run (issue: growth under 10% over 2,000 frames).

Renders FRAMES frames of one class in one Blender renderer, in this process,
moving only the camera and switching mesh instance every 936 frames as a real
run does, and prints resident memory (VmRSS) and peak (VmHWM) after the first
100 frames and at the end. Workers are also recycled after --recycle-after
shards (default 16) in real runs, which bounds any growth further. Progress on stderr (a bar on
a terminal, a line every $SPM_PROGRESS_EVERY s, default 10, elsewhere).
"""

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from spm_data.jobs.progress import stage  # noqa: E402
from spm_data.core.paths import camera_path  # noqa: E402
from spm_data.render import make_renderer  # noqa: E402
from spm_data.core.instances import load_instance  # noqa: E402
from spm_data.core.specs import find_spec, load_spec  # noqa: E402


def memory_mb() -> tuple[float, float]:
    fields = dict(line.split(":", 1) for line in Path("/proc/self/status").read_text().splitlines() if ":" in line)
    kb = lambda key: float(fields[key].split()[0])  # noqa: E731
    return kb("VmRSS") / 1024, kb("VmHWM") / 1024


def main(frames: int = 2000, samples: int = 4) -> None:
    from dataclasses import replace

    spec = load_spec(find_spec("cup"))
    spec = spec.replace(render=replace(spec.render, renderer="blender",
                                       blender=replace(spec.render.blender, samples=samples)))
    renderer = make_renderer(spec, "blender")
    path = camera_path(spec.camera, spec.seed)
    R, t = path.poses()
    started = time.perf_counter()
    first = None
    with stage(f"blender_memory: rendering {frames} frames in Blender", frames, "frame") as progress:
        for k in range(frames):
            inst, idx = divmod(k, len(path))
            if idx == 0:
                renderer.set_mesh(load_instance(spec, inst % spec.mesh.instances))
            renderer.render(R[idx], t[idx])
            if k == 99:
                first = memory_mb()
            progress(1)
    last = memory_mb()
    growth = 100 * (last[0] - first[0]) / first[0]
    print(f"{frames} frames, Cycles {samples} samples, 128x128, {time.perf_counter() - started:.0f} s")
    print(f"| point | RSS MB | peak RSS MB |\n|---|---|---|\n| after 100 frames | {first[0]:.0f} | {first[1]:.0f} |\n"
          f"| after {frames} frames | {last[0]:.0f} | {last[1]:.0f} |")
    print(f"RSS growth from frame 100 to {frames}: {growth:+.1f}% (target: under 10%)")


if __name__ == "__main__":
    main()
