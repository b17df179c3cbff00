"""The paper's Fig. 5 as it ran it: every method trained on a camera grid, tested on views
at random poses within the grid's range (off the grid), occluded 0-95% by rectangles
(spm-data occlude) and by 3-D distractors ([distractors]); seen instances and, as a second
table, unseen instances of the same classes. Prints every method's curve (sum < 5°, sum < 3°,
±5° per bin) and the issue's N3M targets, and leaves the report in OUT/report.

    python benchmarks/fig5.py --out out/fig5                      # 6 classes, 128 px
    python benchmarks/fig5.py --out out/fig5-256 --size 256       # the N3M targets' size
    python benchmarks/fig5.py --out out/fig5-q --quick            # make demo's: 2 classes, small

Folders: OUT/specs (the generated specs), OUT/train (the grid), OUT/test/{clean,occluded,
distractors}, OUT/report. Everything resumes: rerun to reuse what is rendered and cached.
The command it runs last is the documented one: spm train OUT/train --test OUT/test.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from spm_data.commands.occlude_jobs import occlude_dataset  # noqa: E402
from spm_data.commands.render_jobs import load_run_specs, render_dataset  # noqa: E402
from spm_data.jobs import make_executor  # noqa: E402
from spm_model.commands.train import train  # noqa: E402
from spm_model.spm.features import FeatureConfig  # noqa: E402

CLASSES = ("box", "car", "motorcycle", "ball", "animal4", "cup")
SPEC = """class = "{cls}"
seed = 0
[mesh]
instances = {instances}
[camera]
azimuth = [0, {az_stop}, {step}]
elevation = [0, 60, {step}]
distances = [0.6, 0.7, 0.8]
{sampler}
[image]
width = {size}
height = {size}
[render]
renderer = "pyrender"
frames_per_shard = 256
{extra}"""
SPHERE = 'sampler = "sphere"\nviews = {views}\nelevation_range = [0, 60]\ndistance_range = [0.6, 0.8]'
DISTRACTORS = """[distractors]
count = 2
visible = [0.05, 1.0]
classes = ["box", "ball", "car", "animal4"]
instances = 4
scale = [0.6, 1.2]
depth = [0.4, 0.7]
"""


def write_specs(folder: Path, classes, *, size, step, views, instances, kind) -> list[Path]:
    """One spec per class: ``kind`` "train" (the grid, ``instances`` instances), "test" (``views``
    random views within the grid's range, one more instance: unseen) or "clutter" (the same
    views with distractors)."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for cls in classes:
        sampler = "" if kind == "train" else SPHERE.format(views=views)
        text = SPEC.format(cls=cls, instances=instances + (kind != "train"), az_stop=360 - step, step=step,
                           sampler=sampler, size=size, extra=DISTRACTORS if kind == "clutter" else "")
        path = folder / f"{cls}.toml"
        path.write_text(text)
        paths.append(path)
    return paths


def render(paths, out: Path, executor) -> None:
    if (out / "manifest.json").exists():
        return
    render_dataset(load_run_specs(spec_files=paths), out, executor=executor)


def build(args, executor) -> dict:
    out = Path(args.out)
    sizes = dict(size=args.size, step=args.step, views=args.views, instances=args.instances)
    started = time.perf_counter()
    render(write_specs(out / "specs" / "train", args.classes, kind="train", **sizes), out / "train", executor)
    render(write_specs(out / "specs" / "test", args.classes, kind="test", **sizes), out / "test" / "clean", executor)
    if not (out / "test" / "occluded" / "manifest.json").exists():
        occlude_dataset(out / "test" / "clean", out / "test" / "occluded", low=0.05, high=0.95,
                        copies=args.copies, seed=1, executor=executor)
    if args.distractors:
        render(write_specs(out / "specs" / "clutter", args.classes, kind="clutter", **sizes),
               out / "test" / "distractors", executor)
    rendered = time.perf_counter() - started
    if args.noise and not (out / "train" / "occluded" / "manifest.json").exists():
        # Beside the grid, inside the training folder: offgrid trains on clean frames unless told otherwise.
        occlude_dataset(out / "train", out / "train" / "occluded", low=0.05, high=0.6, copies=1, seed=2,
                        executor=executor)
    return {"rendered_s": rendered}


def report_curves(summary: dict, title: str) -> None:
    for group, kinds in summary["fig5"].items():
        for kind, curves in kinds.items():
            if kind == "all" and len(kinds) > 1:
                continue
            rows = next(iter(curves.values()))
            bins = [i for i, r in enumerate(rows) if r["frames"]]
            print(f"\n{title}: {group} instances, {kind} (sum<5 / sum<3 / ±5 %, per bin; frames "
                  + " ".join(str(rows[i]["frames"]) for i in bins) + ")")
            print(f"  {'bin':<26}" + "".join(f"{rows[i]['low']:>12.0%}" for i in bins))
            for m, r in curves.items():
                cells = "".join(f"{_cell(r[i]):>12}" for i in bins)
                print(f"  {m:<26}{cells}")


def fig5_line(summary: dict) -> str:
    """One line: every method's sum < 5° success per occlusion bin, seen instances, rectangles."""
    fig5 = summary["fig5"].get("seen") or summary["fig5"]["all"]
    curves = fig5.get("rectangles") or fig5["all"]
    rows = next(iter(curves.values()))
    bins = [i for i, r in enumerate(rows) if r["frames"]]
    cells = " | ".join(f"{m} " + " ".join("–" if r[i]["success_sum5"] is None else f"{r[i]['success_sum5']:.0f}"
                                           for i in bins) for m, r in curves.items())
    lows = "/".join(f"{rows[i]['low']:.0%}" for i in bins)
    return f"Fig. 5 (seen instances, sum < 5° %, at {lows} occlusion): {cells}"


def _cell(row) -> str:
    f = [("–" if row[k] is None else f"{row[k]:.0f}") for k in ("success_sum5", "success_sum3", "success_tol5")]
    return "/".join(f)


def print_targets(summary: dict) -> None:
    """The issue's N3M targets from the seen instances' rectangle curve."""
    curves = (summary["fig5"].get("seen") or {}).get("rectangles") or {}
    rows = curves.get("n3m")
    if not rows:
        print("\nN3M not run: no targets to print")
        return
    clean, at40 = rows[0], rows[4]
    print(f"\nN3M targets (seen instances, rectangles): 0-10% occluded: ±5° {_pct(clean['success_tol5'])} "
          f"(target >= 95), geodesic median {_num(clean['geodesic_median_deg'])}° (target <= 1), translation "
          f"median {_num(clean.get('translation_median_mm'))} mm (target <= 3); 40-50% occluded: ±5° "
          f"{_pct(at40['success_tol5'])} (target >= 80)")


def _pct(v):
    return "–" if v is None else f"{v:.1f}%"


def _num(v):
    return "–" if v is None else f"{v:.2f}"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="out/fig5")
    parser.add_argument("--classes", default=",".join(CLASSES))
    parser.add_argument("--size", type=int, default=128, help="image side, pixels")
    parser.add_argument("--step", type=int, default=10, help="training grid step, degrees (the paper's: 5)")
    parser.add_argument("--views", type=int, default=50, help="random test views per instance")
    parser.add_argument("--instances", type=int, default=1, help="seen instances per class (one more is unseen)")
    parser.add_argument("--copies", type=int, default=2, help="occluded copies of each test view")
    parser.add_argument("--no-distractors", dest="distractors", action="store_false")
    parser.add_argument("--noise", action="store_true", help="also train with occluded copies (Appendix)")
    parser.add_argument("--methods", default=None, help="built-in methods (default all)")
    parser.add_argument("--runs", type=int, default=1)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--quick", action="store_true",
                        help="make demo's size: box and cup, 20° grid, 12 views, one copy, no distractors")
    args = parser.parse_args(argv)
    if args.quick:
        args.classes, args.step, args.views, args.copies, args.distractors = "box,cup", 20, 12, 1, False
    args.classes = [c for c in args.classes.split(",") if c]
    executor = make_executor(workers=args.workers)
    timing = build(args, executor)
    out = Path(args.out)
    methods = args.methods.split(",") if args.methods else None
    started = time.perf_counter()
    result = train(out / "train", out / "report", test=out / "test", runs=args.runs, executor=executor,
                   features=FeatureConfig(), builtins=methods, command=f"python benchmarks/fig5.py --out {out}")
    trained = time.perf_counter() - started
    if args.quick:
        print(fig5_line(result["summary"]))
        return 0
    print(result["text"])
    report_curves(result["summary"], "Fig. 5")
    print_targets(result["summary"])
    if args.noise:
        noisy = train(out / "train", out / "report-noise", test=out / "test", runs=args.runs, executor=executor,
                      builtins=methods, train_occluded=True, command="fig5 --noise")
        report_curves(noisy["summary"], "Fig. 5, trained with noise (occluded copies)")
    print(f"\nrender {timing['rendered_s']:.0f} s, train and test {trained:.0f} s; report: {out / 'report'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
