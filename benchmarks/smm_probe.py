"""SMM (spm_model/methods/smm.py) on a small render of its own: pose-class accuracy in
its bins, +-5 degree per-angle success, translation error, fit and predict speed.

    PYOPENGL_PLATFORM=egl python benchmarks/smm_probe.py [--out /tmp/smm_probe] [--classes car,box,cup]

Renders (pyrender, 128x128, once; reused when made with the same --classes, --instances and
--views, refused otherwise) per class and instance a
training grid (azimuth 0-355 every 5 degrees, elevation 10-40 every 10: 288 views,
one camera path each) and a test set of random views in the same range (the
``sphere`` sampler, off the grid). Trains on every grid view, tests on the random
ones with only rgb, mask and K.
Progress on stderr (a bar on a terminal, a line every $SPM_PROGRESS_EVERY s, default 10, elsewhere).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from spm_data.jobs.progress import stage  # noqa: E402
from out_options import claim  # noqa: E402
from spm_data.pipelines.render_jobs import load_run_specs, render_dataset  # noqa: E402
from spm_data.io.shards import read_shard  # noqa: E402
from spm_model.methods.smm import SMMPose, pose_bins  # noqa: E402

GRID = """class = "{cls}"
seed = 5
[mesh]
instances = {instances}
[camera]
azimuth = [0, 355, 5]
elevation = [10, 40, 10]
distances = [0.6, 0.7, 0.8]
[image]
width = 128
height = 128
[render]
renderer = "pyrender"
frames_per_shard = 4096
"""
RANDOM = GRID.replace('[camera]', '[camera]\nsampler = "sphere"\nviews = {views}\nelevation_range = [10, 40]')


def render(out: Path, classes, instances: int, views: int) -> None:
    """Render (or resume) into ``out``; a folder made with other --classes, --instances or --views
    is refused (out_options.py), and its specs are never rewritten under their shards."""
    claim(out, {"--classes": list(classes), "--instances": instances, "--views": views},
          record="smm-probe-options.json",
          data=("grid", "random", "specs-grid", "specs-random"), script="smm_probe.py")
    for name, text in (("grid", GRID), ("random", RANDOM)):
        specs = out / f"specs-{name}"
        specs.mkdir(parents=True, exist_ok=True)
        for cls in classes:
            if not (specs / f"{cls}.toml").exists():
                (specs / f"{cls}.toml").write_text(text.format(cls=cls, instances=instances, views=views))
        with stage(f"smm_probe: rendering the {name} views into {out / name}", unit="frame") as progress:
            render_dataset(load_run_specs(all_classes=True, specs_dir=specs), out / name, progress=progress)


def load(folder: Path, fields=("rgb", "mask", "K", "pose", "path_index", "instance_id")):
    frames, poses = [], []
    for s, shard in enumerate(sorted(folder.rglob("*.h5"))):
        data = read_shard(shard, fields)
        for i in range(len(data["rgb"])):
            frames.append({"rgb": data["rgb"][i], "mask": data["mask"][i] > 0, "K": data["K"][i],
                           "sequence": s * 1000 + int(data["instance_id"][i]),
                           "path_index": int(data["path_index"][i])})
            poses.append(data["pose"][i])
    return frames, np.array(poses)


def angle_error(a, b):
    return np.abs((a - b + 180.0) % 360.0 - 180.0)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="/tmp/smm_probe")
    ap.add_argument("--classes", default="car,box,cup,animal4,motorcycle,ball")
    ap.add_argument("--instances", type=int, default=2)
    ap.add_argument("--views", type=int, default=40, help="random test views per instance")
    ap.add_argument("--bins", type=int, default=8)
    ap.add_argument("--unseen", action="store_true",
                    help="train on every instance but the last of each class, test on the last (unseen instances)")
    ap.add_argument("--parts", type=int, default=48, help="parts kept by the selection")
    ap.add_argument("--candidate-parts", type=int, default=96)
    ap.add_argument("--alignment-weight", type=float, default=1.0)
    args = ap.parse_args(argv)
    out = Path(args.out)
    render(out, args.classes.split(","), args.instances, args.views)
    with stage("smm_probe: reading the frames"):
        train, train_poses = load(out / "grid")
        test, test_poses = load(out / "random")
    if args.unseen:
        last = args.instances - 1
        keep = np.array([f["sequence"] % 1000 != last for f in train])
        train, train_poses = [f for f, k in zip(train, keep) if k], train_poses[keep]
        new = np.array([f["sequence"] % 1000 == last for f in test])
        test, test_poses = [f for f, k in zip(test, new) if k], test_poses[new]
    test = [{k: f[k] for k in ("rgb", "mask", "K")} for f in test]
    order = np.random.default_rng(0).permutation(len(test))
    test, test_poses = [test[i] for i in order], test_poses[order]
    model = SMMPose(n_bins=args.bins, parts=args.parts, candidate_parts=args.candidate_parts,
                    alignment_weight=args.alignment_weight)
    start = time.perf_counter()
    with stage(f"smm_probe: fitting SMM on {len(train)} frames"):
        model.fit(train, train_poses)
    fit_s = time.perf_counter() - start
    start = time.perf_counter()
    with stage(f"smm_probe: predicting {len(test)} frames"):
        pred = model.predict(test)
    bins = pose_bins(pred, args.bins)
    predict_s = time.perf_counter() - start
    truth = pose_bins(test_poses, args.bins)
    ok = np.isfinite(pred).all(axis=1)
    per_angle = np.where(ok[:, None], angle_error(pred[:, :3], test_poses[:, :3]) <= 5.0, False)
    within = per_angle.all(axis=1)
    t_err = np.abs(pred[ok, 3:] - test_poses[ok, 3:]) * 1000.0
    counts = np.bincount(truth, minlength=args.bins)
    print(f"train {len(train)} grid frames, test {len(test)} random views ({'unseen' if args.unseen else 'the same'} "
          f"instances); classes {args.classes}")
    print(f"fit {fit_s:.1f} s; predict {len(test) / predict_s:.1f} frames/s (2 shared cores: noisy)")
    print(f"selected parts {list(model.selected_)} of {model.candidate_parts}")
    print(f"pose-class accuracy ({args.bins} azimuth bins): {np.mean(bins == truth):.3f} "
          f"(chance: majority {counts.max() / counts.sum():.3f}, uniform {1 / args.bins:.3f})")
    print(f"within +-5 deg on all three angles: {within.mean():.3f} (rx {per_angle[:, 0].mean():.3f}, "
          f"ry {per_angle[:, 1].mean():.3f}, rz {per_angle[:, 2].mean():.3f}); estimates {ok.mean():.3f}")
    print(f"translation median |error| x, y, z mm: {np.round(np.median(t_err, axis=0), 1).tolist()}")


if __name__ == "__main__":
    main()
