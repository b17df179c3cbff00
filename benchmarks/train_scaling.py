"""SPM training at scale, feature-extraction speed, prediction speed at 640x480,
the ellipse fits' cost, and the scalable solver's accuracy against the exact l1 solve.

    python benchmarks/train_scaling.py [DIR] [--sizes 5000,20000,100000,250000]
    python benchmarks/train_scaling.py DIR --accuracy-only [--seeds 8]
        [--measure docs/results/measures/spm-solvers.json]

Features come from real renders: DIR (default: a fresh pyrender set of the six
built-in classes at 128x128, 1,296 frames, rendered into a temporary folder).
Training sets larger than the frames extracted are made by resampling those
feature vectors with small Gaussian jitter (sigma 0.005 on unit vectors); the
timing depends on n, not on where the vectors came from. Targets: 250,000
samples in under 30 minutes on this machine; the scalable solver (exact l1 for
a 1,000-sample subset, Nystrom regressor) within one point of the exact l1
solve over every sample; prediction at 25 images per second or better. --accuracy-only: only that
comparison (README.md quotes it: --measure writes its figures, each solver's fit in CPU seconds
and how they were made, for scripts/results_doc.py's spm-solvers table). A line on stderr as each
step starts, and progress while it runs (a bar on a terminal, a line every $SPM_PROGRESS_EVERY s,
default 10, elsewhere).
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import shlex
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from spm_data.jobs.progress import stage, tracked  # noqa: E402
from spm_data.pipelines.render_jobs import load_run_specs, render_dataset  # noqa: E402
from spm_data.io.shards import read_shard  # noqa: E402
from spm_model.bench.feature_cache import find_shards, load_features  # noqa: E402
from spm_model.spm.ellipse import fit_ellipse  # noqa: E402
from spm_model.spm.estimator import SPMEstimator  # noqa: E402
from spm_model.bench.protocols import splits  # noqa: E402
from spm_model.bench.extract import frames_features  # noqa: E402
from spm_model.spm.features import FeatureConfig  # noqa: E402
from spm_model.bench.metrics import pose_errors, summarise  # noqa: E402
from spm_data.jobs.executor import LocalExecutor  # noqa: E402
from spm_data.io.files import write_json_atomic  # noqa: E402


def make_shards(folder: Path) -> Path:
    """Six classes x 216 consecutive views (azimuth 0-355, elevation 20-30), pyrender 128x128."""
    specs = load_run_specs(all_classes=True)
    from dataclasses import replace

    from spm_data.core.paths import AngleRange

    specs = [replace(s, camera=replace(s.camera, elevation=AngleRange(20, 30, 5)),
                     mesh=replace(s.mesh, instances=1),
                     render=replace(s.render, renderer="pyrender")) for s in specs]
    with stage(f"train_scaling: rendering {folder}", unit="frame") as progress:
        render_dataset(specs, folder, progress=progress)
    return folder


def extraction_fps(shards: Path, frames: int = 256) -> tuple[float, float]:
    """Frames per second of feature extraction in one process, PSO and direct ellipse."""
    shard = find_shards(shards)[0]
    d = read_shard(shard, ("rgb", "mask", "instance_id", "path_index"), frames=slice(0, frames))
    out = []
    for ellipse in ("pso", "direct"):
        progress = stage(f"train_scaling: features of {len(d['rgb'])} frames, one process, {ellipse} ellipse",
                         len(d["rgb"]), "frame")
        started = time.perf_counter()
        with progress:
            frames_features(d["rgb"], d["mask"], d["instance_id"], d["path_index"], FeatureConfig(ellipse=ellipse),
                            progress)
        out.append(len(d["rgb"]) / (time.perf_counter() - started))
    return out[0], out[1]


def ellipse_timing(table) -> tuple[float, float]:
    from spm_model.spm.bunches import fit_bunches
    from spm_model.spm.keypoints import sift_keypoints

    shard = find_shards(table)[0]
    d = read_shard(shard, ("rgb", "mask"), frames=slice(0, 100))
    centres = []
    with stage("train_scaling: ellipse fits' cost"):
        for rgb, mask in zip(d["rgb"], d["mask"]):
            loc, _ = sift_keypoints(rgb, mask)
            if len(loc) >= 16:
                centres.append(fit_bunches(loc).means)
    times = []
    for method in ("pso", "direct"):
        started = time.perf_counter()
        for c in centres:
            fit_ellipse(c, method=method)
        times.append(1000 * (time.perf_counter() - started) / len(centres))
    return times[0], times[1]


def resample(X, y, n, rng):
    idx = rng.integers(len(X), size=n)
    Xn = X[idx] + rng.normal(0, 0.005, (n, X.shape[1]))
    return Xn / np.linalg.norm(Xn, axis=1, keepdims=True), y[idx]


def accuracy_against_exact(table, subset: int = 1200, seeds=(0, 1, 2)) -> dict:
    """Views protocol on up to ``subset`` training frames: the default solver (exact
    l1 for a 1,000-sample subset) and the knn solver against the exact l1 over every training frame,
    each fitted with several seeds (the noise copies and Nystrom centres vary with
    the seed, and that variation is of the same size as the difference sought)."""
    (_, train, test), = splits(table, "views", seed=0)
    train = train[np.isfinite(table.train_vector[train]).all(axis=1)][:subset]
    test = test[np.isfinite(table.query_vector[test]).all(axis=1)]
    out = {}
    for name, params in (("exact l1, every sample", {"projection": "exact", "projection_samples": len(train)}),
                         ("exact l1, 1,000-sample subset (default)", {}),
                         ("knn l1 (k=64), 1,000-sample subset", {"projection": "knn"})):
        rows = []
        for seed in tracked(seeds, f"train_scaling: {name}, {len(train)} training frames", "seed"):
            started, cpu = time.perf_counter(), time.process_time()
            model = SPMEstimator(**params, seed=seed).fit(table.train_vector[train], table.pose[train])
            fit_s, fit_cpu_s = time.perf_counter() - started, time.process_time() - cpu
            new = summarise(pose_errors(model.predict(table.query_vector[test]), table.pose[test]))
            own = summarise(pose_errors(model.predict(table.train_vector[train]), table.pose[train]))
            rows.append((new["success_sum5"], own["success_sum5"], own["success_sum3"], fit_s,   # the sum criterion
                         fit_cpu_s))
        out[name] = (np.array(rows), len(train), len(test))
    return out


def predict_fps(model, shards: Path, repeats: int = 40) -> float:
    import cv2

    shard = find_shards(shards)[0]
    rgb = read_shard(shard, ("rgb",), frames=slice(5, 6))["rgb"][0]
    big = cv2.resize(rgb, (640, 480), interpolation=cv2.INTER_CUBIC)
    model.predict_image(big)  # warm up
    started = time.perf_counter()
    for _ in range(repeats):
        model.predict_image(big)
    return repeats / (time.perf_counter() - started)


SOLVERS = {"exact l1, every sample": "exact_all", "exact l1, 1,000-sample subset (default)": "exact_subset",
           "knn l1 (k=64), 1,000-sample subset": "knn_subset"}


def accuracy_figures(found: dict, frames: int) -> dict:
    """The measure's summary: per solver (SOLVERS' keys), the mean and σ over seeds of each rate
    and the mean fit time (wall and CPU seconds); the sizes they were measured on."""
    out = {"frames": frames, "solvers": {}}
    for name, (rows, n_train, n_test) in found.items():
        mean, std = rows.mean(axis=0), rows.std(axis=0)
        out.update({"training_frames": n_train, "test_frames": n_test, "seeds": len(rows)})
        out["solvers"][SOLVERS[name]] = {
            "new_sum5": round(float(mean[0]), 2), "new_sum5_std": round(float(std[0]), 2),
            "own_sum5": round(float(mean[1]), 2), "own_sum5_std": round(float(std[1]), 2),
            "own_sum3": round(float(mean[2]), 2), "own_sum3_std": round(float(std[2]), 2),
            "fit_s": round(float(mean[3]), 2), "fit_cpu_s": round(float(mean[4]), 2)}
    return out


def write_measure(path: Path, summary: dict, command: str, wall_s: float) -> None:
    spec = importlib.util.spec_from_file_location("results_doc", ROOT / "scripts" / "results_doc.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    made = module.made_block(command, wall_s, cpu_s=module.cpu_seconds())
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(path, {"summary": summary, "made": made}, sort_keys=False)


def speeds(shards: Path, tmp: str) -> None:
    """Feature extraction in one process and from shards with 1 and 2 workers (printed)."""
    pso_fps, direct_fps = extraction_fps(shards)
    print(f"feature extraction, one process: {pso_fps:.1f} frames/s (PSO ellipse), {direct_fps:.1f} (direct)")
    sample = Path(tmp) / "sample"
    sample.mkdir()
    for shard in find_shards(shards)[:4]:
        shutil.copy(shard, sample / shard.name)
    for workers in (1, 2):
        for old in sample.glob(".spm-features/*"):
            old.unlink()
        with stage(f"train_scaling: features of 4 shards, {workers} worker(s)") as progress:
            started = time.perf_counter()
            n = len(load_features(sample, executor=LocalExecutor(workers=workers), progress=progress))
            elapsed = time.perf_counter() - started
        print(f"feature extraction of {n} frames (4 shards, no cache) with {workers} worker(s): "
              f"{elapsed:.1f} s, {n / elapsed:.1f} frames/s")


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("shards", nargs="?", type=Path, default=None,
                        help="folder of shards (default: a fresh pyrender set in a temporary folder)")
    parser.add_argument("--shards", dest="old_shards", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--sizes", default="5000,20000,100000,250000", help="training-set sizes, comma-separated")
    parser.add_argument("--workers", type=int, default=2, help="feature-extraction processes")
    parser.add_argument("--accuracy-only", action="store_true", help="only the exact-solve comparison")
    parser.add_argument("--seeds", type=int, default=3, help="seeds per solver in the exact-solve comparison")
    parser.add_argument("--measure", type=Path, help="with --accuracy-only: write its figures to this JSON")
    args = parser.parse_args(argv)
    if args.old_shards:  # the old spelling, kept for one release
        print("warning: --shards is deprecated; give the folder as the first argument", file=sys.stderr)
        args.shards = args.old_shards
    if args.measure and not (args.accuracy_only and args.shards):
        parser.error("--measure goes with --accuracy-only and a shards folder")
    started = time.monotonic()
    with tempfile.TemporaryDirectory() as tmp:
        shards = args.shards or make_shards(Path(tmp) / "shards")
        if not args.accuracy_only:
            speeds(shards, tmp)
        with stage(f"train_scaling: features of {shards}") as progress:   # cached after a first spm train
            table = load_features(shards, executor=LocalExecutor(workers=args.workers), progress=progress)
        if not args.accuracy_only:
            pso_ms, direct_ms = ellipse_timing(shards)
            print(f"ellipse fit per frame: PSO (Eq. 1) {pso_ms:.2f} ms, direct {direct_ms:.3f} ms "
                  f"({pso_ms / direct_ms:.0f}x)")

        found = accuracy_against_exact(table, seeds=range(args.seeds))
        for name, (rows, n_train, n_test) in found.items():
            mean, std = rows.mean(axis=0), rows.std(axis=0)
            print(f"{name}, {n_train} training frames, seeds 0-{len(rows) - 1}: fit {mean[3]:.1f} s ({mean[4]:.1f} "
                  f"CPU s); success<5 on {n_test} new views {mean[0]:.1f}% (sigma {std[0]:.1f}); on its training "
                  f"frames success<5 {mean[1]:.1f}% (sigma {std[1]:.1f}), <3 {mean[2]:.1f}% (sigma {std[2]:.1f})")
        if args.measure:
            write_measure(args.measure, accuracy_figures(found, len(table)),
                          shlex.join(["python", "benchmarks/train_scaling.py", *argv]), time.monotonic() - started)
        if args.accuracy_only:
            return 0
        ok = np.isfinite(table.train_vector).all(axis=1)
        X, y = table.train_vector[ok], table.pose[ok]
        rng = np.random.default_rng(0)
        print("| samples | training time (s) |\n|---|---|")
        model = None
        for n in (int(v) for v in args.sizes.split(",")):
            Xn, yn = resample(X, y, n, rng)
            started = time.perf_counter()
            with stage(f"train_scaling: SPM fitted on {n:,} samples"):
                model = SPMEstimator().fit(Xn, yn)
            print(f"| {n:,} | {time.perf_counter() - started:.1f} |", flush=True)
        with stage("train_scaling: spm predict at 640x480"):
            fps = predict_fps(model, shards)
        print(f"spm predict, 640x480 image (features + model, image in memory): {fps:.1f} images/s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
