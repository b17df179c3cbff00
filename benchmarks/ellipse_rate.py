"""The ellipse fit's and initial manifold's cost per call, and (with ``--old``) their
numbers and cost against another checkout's spm_model/spm/{ellipse,manifold}.py.

    python benchmarks/ellipse_rate.py [--shards DIR] [--random 3000] [--old ROOT] [--repeats 5]

Inputs: gamma = 8 cluster centres as SPM's features make them (SIFT keypoints of
DIR's frames, at their own size and resized to 640x480, then fit_bunches), and
``--random`` sets of 8 Gaussian points with spreads of 5-200 px. With ``--old``,
prints per method ("pso", "direct") how many manifold vectors and eccentricities
are bit-for-bit equal, how many differ by more than 1e-9, the largest differences,
and the per-call CPU time (time.process_time, best of ``--repeats`` interleaved
passes over the first 200 inputs) of old and new.

Progress on stderr (a bar on a terminal, a line every $SPM_PROGRESS_EVERY s, default 10, elsewhere).
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from spm_data.jobs.progress import stage  # noqa: E402
from spm_model.spm import manifold as new_manifold  # noqa: E402
from spm_model.spm.ellipse import EllipseError  # noqa: E402


def centres_from_shards(shards: Path) -> list[np.ndarray]:
    """(8, 2) EM centres of every frame's SIFT keypoints, as spm_model.spm.features makes them."""
    import cv2

    from spm_data.io.shards import read_attrs, read_shard
    from spm_model.bench.feature_cache import find_shards
    from spm_model.spm.bunches import BunchError, fit_bunches
    from spm_model.spm.features import FeatureConfig, working_image
    from spm_model.spm.keypoints import sift_locations

    out = []
    paths = find_shards(shards)
    frames = sum(int(read_attrs(path)["frames"]) for path in paths)
    with stage(f"ellipse_rate: keypoint centres of {shards}'s frames", frames, "frame") as progress:
        for path in paths:
            data = read_shard(path, ("rgb", "mask"))
            for rgb, mask in zip(data["rgb"], data["mask"]):
                big = cv2.resize(np.ascontiguousarray(rgb), (640, 480), interpolation=cv2.INTER_CUBIC)
                for image, m in ((rgb, mask), (big, None)):
                    locations = sift_locations(*working_image(image, m, FeatureConfig().max_side))
                    try:
                        out.append(fit_bunches(locations, gamma=8, seed=0).means)
                    except BunchError:
                        pass
                progress(1)
    return out


def random_centres(count: int, seed: int = 1) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.normal(0, 1, (8, 2)) * rng.uniform(5, 200) + rng.uniform(0, 640, 2) for _ in range(count)]


def load_old(root: Path):
    """The manifold module of another checkout, importing that checkout's ellipse module."""
    spec = importlib.util.spec_from_file_location("old_ellipse", root / "spm_model/spm/ellipse.py")
    ellipse = importlib.util.module_from_spec(spec)
    sys.modules["old_ellipse"] = ellipse
    spec.loader.exec_module(ellipse)
    source = (root / "spm_model/spm/manifold.py").read_text()
    module = type(sys)("old_manifold")
    exec(compile(source.replace("from spm_model.spm.ellipse import", "from old_ellipse import"),  # noqa: S102
                 str(root / "spm_model/spm/manifold.py"), "exec"), module.__dict__)
    return module, ellipse.EllipseError


def manifold(module, errors, points, method):
    try:
        return module.initial_manifold(points, method=method)
    except errors as exc:
        return str(exc)


def compare(old, old_errors, sets, method: str, progress=lambda n: None) -> str:
    equal = over = 0
    dv = de = 0.0
    for points in sets:
        progress(1)
        a, b = manifold(old, old_errors, points, method), manifold(new_manifold, EllipseError, points, method)
        if isinstance(a, str) or isinstance(b, str):
            equal += a == b
            over += a != b
            continue
        dv, de = max(dv, float(np.abs(a[0] - b[0]).max())), max(de, abs(a[1] - b[1]))
        equal += bool(np.array_equal(a[0], b[0]) and a[1] == b[1])
        over += max(np.abs(a[0] - b[0]).max(), abs(a[1] - b[1])) > 1e-9
    return (f"{len(sets)} inputs, bit-for-bit equal {equal}, differ by > 1e-9: {over}, "
            f"largest |d vector| {dv:.3g}, |d eccentricity| {de:.3g}")


def per_call(modules, errors, sets, method: str, repeats: int) -> list[float]:
    """Best-of-``repeats`` CPU ms per initial_manifold call of each module, passes interleaved."""
    best = [np.inf] * len(modules)
    for _ in range(repeats):
        for i, (module, error) in enumerate(zip(modules, errors)):
            t = time.process_time()
            for points in sets:
                manifold(module, error, points, method)
            best[i] = min(best[i], (time.process_time() - t) / len(sets) * 1e3)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shards", type=Path)
    parser.add_argument("--random", type=int, default=3000)
    parser.add_argument("--old", type=Path, help="root of a checkout to compare with")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    groups = {"random": random_centres(args.random)}
    if args.shards:
        groups = {"frames": centres_from_shards(args.shards), **groups}
    modules, errors = [new_manifold], [EllipseError]
    if args.old:
        old, old_errors = load_old(args.old)
        modules, errors = [old, new_manifold], [old_errors, EllipseError]
    for name, sets in groups.items():
        for method in ("pso", "direct"):
            with stage(f"ellipse_rate: {name} {method}, {args.repeats} timed passes over {len(sets[:200])} inputs"):
                times = per_call(modules, errors, sets[:200], method, args.repeats)
            line = f"{name} {method}: " + ", ".join(f"{t:.3f} ms" for t in times) + " per call"
            if args.old:
                with stage(f"ellipse_rate: {name} {method}, old and new compared", len(sets), "input") as progress:
                    line += f" (old/new {times[0] / times[1]:.2f}x); " + compare(old, old_errors, sets, method,
                                                                                   progress)
            print(line, flush=True)


if __name__ == "__main__":
    main()
