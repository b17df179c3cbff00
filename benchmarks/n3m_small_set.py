"""N3M (marker levels only, and with its RANSAC fallback) and SIFT + PnP on the tests' small set.

    python benchmarks/n3m_small_set.py WORK [--snapshot docs/results/measures/n3m-small-set.json]

The set (tests/conftest.py ``model_shards``, rendered into WORK/shards): box, car and cup, one
instance each, 128 px, azimuth 0-115 degrees in 5-degree steps at elevations 20 and 25, 0.6 m
(pyrender). Even path steps train (72 frames, with depth); the 72 odd ones are tested, 5 degrees
from a training view, clean and with 40% of the object under a rectangle (`spm-data occlude
--min 0.4 --max 0.4 --seed 1`, into WORK/hidden; the method is given the visible mask). Per
method and test set: frames within 5 degrees on all three angles, frames with an estimate, and
how many poses came from a marker and how many from RANSAC over all matches. docs/method.md
("SIFT + PnP") quotes them from the snapshot (scripts/results_doc.py --blocks).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from spm_data.pipelines.occlude_jobs import occlude_dataset  # noqa: E402
from spm_data.pipelines.render_jobs import load_run_specs, render_dataset  # noqa: E402
from spm_data.io.shards import read_shard  # noqa: E402
from spm_model.methods.n3m import N3MPose  # noqa: E402
from spm_model.methods.sift_pnp import SiftPnPPose  # noqa: E402
from tests.helpers import within_5_degrees, write_pyrender_128_spec  # noqa: E402

METHODS = {"n3m": lambda: N3MPose(), "n3m-fallback": lambda: N3MPose(ransac_fallback=True),
           "sift-pnp": lambda: SiftPnPPose()}


def make_sets(work: Path) -> tuple[Path, Path]:
    """The small set's shards and their 40%-hidden copies (rendered and occluded once)."""
    shards, hidden = work / "shards", work / "hidden"
    if not (shards / "manifest.json").exists():
        specs = work / "specs"
        specs.mkdir(parents=True, exist_ok=True)
        for cls in ("box", "car", "cup"):
            write_pyrender_128_spec(specs, cls, seed=1, az_stop=115, el=20, per_shard=48)
        render_dataset(load_run_specs(all_classes=True, specs_dir=specs), shards)
    if not (hidden / "manifest.json").exists():
        occlude_dataset(shards, hidden, low=0.4, high=0.4, seed=1)
    return shards, hidden


def split(shards: Path, mask_key: str = "mask"):
    """(train frames, their poses, test frames, their poses): even path steps train, odd ones test."""
    train, poses, test, truth = [], [], [], []
    for s, path in enumerate(sorted(shards.glob("*.h5"))):
        data = read_shard(path, ("rgb", "mask", "depth", "K", "pose", "path_index") +
                          ((mask_key,) if mask_key != "mask" else ()))
        for i, step in enumerate(data["path_index"]):
            if step % 2 == 0:
                train.append({"rgb": data["rgb"][i], "mask": data["mask"][i] > 0, "K": data["K"][i],
                              "depth": data["depth"][i], "sequence": s})
                poses.append(data["pose"][i])
            else:
                test.append({"rgb": data["rgb"][i], "mask": data[mask_key][i] > 0, "K": data["K"][i]})
                truth.append(data["pose"][i])
    return train, np.array(poses), test, np.array(truth)


def measure(shards: Path, hidden: Path) -> dict:
    train, poses, clean, truth = split(shards)
    _, _, occluded, truth_hidden = split(hidden, "visible_mask")
    out = {}
    for name, make in METHODS.items():
        model = make().fit(train, poses)
        out[name] = {}
        for kind, frames, true in (("clean", clean, truth), ("hidden", occluded, truth_hidden)):
            pred, sources = model.predict_details(frames)
            out[name][kind] = {"frames": len(frames), "within_5": int(within_5_degrees(pred, true).sum()),
                               "estimated": int(np.all(np.isfinite(pred), axis=1).sum()),
                               "from_markers": sources.count("n3m"), "from_ransac": sources.count("ransac")}
    return out


def _made_block(command: str, wall_s: float) -> dict:
    spec = importlib.util.spec_from_file_location("results_doc", ROOT / "scripts" / "results_doc.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.made_block(command, wall_s)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("work", type=Path)
    parser.add_argument("--snapshot", type=Path, help="write the figures and how they were made to this JSON")
    args = parser.parse_args(argv)
    start = time.monotonic()
    found = measure(*make_sets(args.work))
    wall = time.monotonic() - start
    for name, sets in found.items():
        print(name, "  ".join(f"{kind}: {s['within_5']}/{s['frames']} within 5 deg, {s['estimated']} estimated, "
                              f"{s['from_markers']} markers / {s['from_ransac']} RANSAC" for kind, s in sets.items()))
    print(f"{wall:.1f} s")
    if args.snapshot:
        snap = {"summary": found, "made": _made_block("python benchmarks/n3m_small_set.py WORK", wall)}
        args.snapshot.parent.mkdir(parents=True, exist_ok=True)
        tmp = args.snapshot.with_name(f".{args.snapshot.name}.partial")
        tmp.write_text(json.dumps(snap, indent=1) + "\n")
        tmp.replace(args.snapshot)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
