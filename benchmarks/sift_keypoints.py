"""Median SIFT keypoints per 128x128 pyrender render, per built-in class (target: >= 30).

Renders every 13th view of each class's default path for all its instances and
counts OpenCV SIFT keypoints on the grey image. Prints a Markdown table.
Progress on stderr (a bar on a terminal, a line every $SPM_PROGRESS_EVERY s, default 10, elsewhere).
"""

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from spm_data.jobs.progress import stage  # noqa: E402
from spm_data.core.paths import camera_path  # noqa: E402
from spm_data.render import make_renderer  # noqa: E402
from spm_data.core.instances import instance_count, load_instance  # noqa: E402
from spm_data.core.specs import all_spec_paths, load_spec  # noqa: E402


def main(stride: int = 13) -> None:
    import cv2

    sift = cv2.SIFT_create()
    print("| class | views | median keypoints | 10th percentile | min |")
    print("|---|---|---|---|---|")
    started = time.perf_counter()
    for spec_path in all_spec_paths():
        spec = load_spec(spec_path)
        renderer = make_renderer(spec, "pyrender")
        path = camera_path(spec.camera, spec.seed)
        R, t = path.poses()
        counts = []
        views = sum(len(range(inst % stride, len(path), stride)) for inst in range(instance_count(spec)))
        with stage(f"sift_keypoints: {spec.class_name}, {views} views", views, "view") as progress:
            for inst in range(instance_count(spec)):
                renderer.set_mesh(load_instance(spec, inst))
                for i in range(inst % stride, len(path), stride):
                    rgb = renderer.render(R[i], t[i])["rgb"]
                    counts.append(len(sift.detect(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), None)))
                    progress(1)
        c = np.array(counts)
        print(f"| {spec.class_name} | {len(c)} | {np.median(c):.0f} | {np.percentile(c, 10):.0f} | {c.min()} |")
    print(f"\n({time.perf_counter() - started:.1f} s)")


if __name__ == "__main__":
    main()
