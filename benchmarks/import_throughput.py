"""Import throughput of a phone-style capture (issue 43): ``spm-data import nerf`` on a
transforms.json listing FRAMES + MISSING frames of which MISSING have no image (skipped, listed),
1080 x 1920 JPEGs (portrait, as phones write them), no masks, no depth.

The photos are made here (nothing is downloaded): a smooth colour field with pixel noise of
+-20 per channel (harsher than most photos: it barely compresses) and a coloured ball
at the object's origin, seen from a circle of cameras looking at it; instant-ngp's layout
(OpenGL camera-to-world, pixel-corner intrinsics). Each run imports into a fresh folder and
runs ``validate`` on it; frames/s counts the frames imported over the whole command's time
(planning, decoding, masks, writing, the manifest).

    python benchmarks/import_throughput.py [--frames 60] [--missing 15] [--mask none|sphere|grabcut]
        [--max-side N] [--repeat 2]

Progress on stderr (a line every $SPM_PROGRESS_EVERY s, default 10).
"""

import argparse
import json
import os
import sys
import tempfile
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from spm_data.jobs.progress import Progress  # noqa: E402
from spm_data.pipelines.validate import validate_folder  # noqa: E402
from spm_data.core.poses import K_to_corner_origin, camera_pose, cv_to_gl_camera_to_world, project_points  # noqa: E402
from spm_data.errors import SpmWarning  # noqa: E402
from spm_data.formats.nerf import import_nerf  # noqa: E402


def write_capture(root: Path, frames: int, missing: int, width: int, height: int) -> Path:
    """The capture: transforms.json listing frames + missing frames, the images of ``frames``."""
    rng = np.random.default_rng(0)
    K = np.array([[1400.0, 0, (width - 1) / 2], [0, 1400.0, (height - 1) / 2], [0, 0, 1]])
    low = cv2.resize(rng.integers(0, 256, (9, 6, 3)).astype(np.uint8), (width, height),
                     interpolation=cv2.INTER_CUBIC)
    (root / "images").mkdir(parents=True)
    listed = []
    skip = set(np.linspace(3, frames + missing - 2, missing).astype(int).tolist()) if missing else set()
    for i in range(frames + missing):
        R, t = camera_pose(360.0 * i / (frames + missing), 20.0, 0.0, 0.8)
        name = f"images/{i:04d}.jpg"
        if i not in skip:
            image = np.clip(np.roll(low, 7 * i, axis=1).astype(np.int16) + rng.integers(-20, 21, low.shape),
                            0, 255).astype(np.uint8)
            uv, _ = project_points(np.zeros((1, 3)), K, R, t)
            cv2.circle(image, tuple(int(v) for v in uv[0]), 330, (230, 180, 40), -1, cv2.LINE_AA)
            cv2.imwrite(str(root / name), image, [cv2.IMWRITE_JPEG_QUALITY, 90])
        listed.append({"file_path": name, "transform_matrix": cv_to_gl_camera_to_world(R, t).tolist()})
    Kc = K_to_corner_origin(K)
    (root / "transforms.json").write_text(json.dumps({"fl_x": Kc[0, 0], "fl_y": Kc[1, 1], "cx": Kc[0, 2],
                                                      "cy": Kc[1, 2], "w": width, "h": height,
                                                      "camera_model": "OPENCV", "frames": listed}))
    return root


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--missing", type=int, default=15)
    parser.add_argument("--width", type=int, default=1080)
    parser.add_argument("--height", type=int, default=1920)
    parser.add_argument("--mask", choices=("none", "sphere", "grabcut"), default="none")
    parser.add_argument("--max-side", type=int, default=None)
    parser.add_argument("--repeat", type=int, default=2)
    args = parser.parse_args(argv)
    warnings.filterwarnings("ignore", category=SpmWarning)   # the skipped frames: counted in the result line
    with tempfile.TemporaryDirectory(prefix="import-throughput-") as tmp:
        capture = write_capture(Path(tmp) / "capture", args.frames, args.missing, args.width, args.height)
        extra = {} if args.mask == "none" else {"radius": 0.3}
        for run in range(args.repeat):
            out = Path(tmp) / f"out{run}"
            load = os.getloadavg()[0]
            started = time.perf_counter()
            with Progress() as progress:
                summary, problems = import_nerf(capture, out, scale=1.0, mask=args.mask, progress=progress, **extra,
                                                **({"max_side": args.max_side} if args.max_side else {}))
            seconds = time.perf_counter() - started
            bad = validate_folder(out)
            size = sum(p.stat().st_size for p in out.iterdir()) / 2**20
            print(f"run {run + 1}: {summary.frames} frames imported, {len(problems)} skipped, {seconds:.1f} s, "
                  f"{summary.frames / seconds:.1f} frames/s, shards {size:.0f} MiB, validate: "
                  f"{'ok' if not bad else bad}, load {load:.1f} at start (--mask {args.mask}, --max-side "
                  f"{args.max_side})")


if __name__ == "__main__":
    main()
