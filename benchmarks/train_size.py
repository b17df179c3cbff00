"""How the `instances` result grows with the frames rendered (issue 48): the default six-class
specs rendered with pyrender at a few sizes (``spm-data render --all --renderer pyrender --limit
N``: N frames per class, spread over each camera path), then ``spm train --protocol instances``
on each with the learned method, the reference and chance, one run. Writes, per size, the
snapshot docs/results/train-size-FRAMES.json (scripts/results_doc.py; docs/results.md's
"Training-set size" table reads them) with the render and train commands and their wall times.

    python benchmarks/train_size.py --sizes 1000,4000,16000 --out out/train-size

A size is the total frames asked for; --limit is that over the six classes, rounded up. The
renders and reports stay in --out; an existing render of a size is reused (its wall time then
is the first run's, kept in OUT/render-FRAMES/render_s.txt).
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import os
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from spm_data.jobs.progress import Progress  # noqa: E402
from spm_data.jobs import make_executor  # noqa: E402
from spm_model.pipelines.train import train  # noqa: E402

CLASSES = 6          # the default specs' classes (render_specs/)
METHODS = ("cnn", "template", "chance")


def results_doc():
    """scripts/results_doc.py as a module (its snapshot writer)."""
    spec = importlib.util.spec_from_file_location("results_doc", ROOT / "scripts" / "results_doc.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def load_line() -> str:
    """The 1-, 5- and 15-minute load averages, as uptime prints them."""
    return "load average " + ", ".join(f"{v:.2f}" for v in os.getloadavg())


def render(frames: int, out: Path, workers: int) -> tuple[Path, str, float]:
    """The render of ``frames`` frames (reused when done before): (folder, command, wall seconds)."""
    limit = math.ceil(frames / CLASSES)
    folder = out / f"render-{frames}"
    command = ["spm-data", "render", "--all", "--renderer", "pyrender", "--limit", str(limit), "--workers",
               str(workers), "--out", str(folder)]
    timing = folder / "render_s.txt"
    if timing.is_file():
        return folder, " ".join(command), float(timing.read_text())
    start = time.perf_counter()
    subprocess.run([str(Path(sys.executable).parent / command[0]), *command[1:]], check=True)
    wall = time.perf_counter() - start
    timing.write_text(f"{wall:.1f}\n")
    return folder, " ".join(command), wall


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default="1000,4000,16000", help="total frames per render, comma-separated")
    parser.add_argument("--out", type=Path, default=Path("out/train-size"))
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--snapshots", type=Path, default=ROOT / "docs" / "results")
    args = parser.parse_args(argv)
    doc = results_doc()
    for frames in (int(s) for s in args.sizes.split(",")):
        print(f"[{frames} frames] {load_line()}", flush=True)
        folder, render_command, render_s = render(frames, args.out, args.workers)
        report = args.out / f"report-{frames}"
        command = (f"spm train {folder} --protocol instances --runs 1 --methods {','.join(METHODS)} "
                   f"--workers {args.workers} --out {report}")
        start = time.perf_counter()
        with Progress() as progress:
            train(folder, report, protocol="instances", runs=1, builtins=list(METHODS), progress=progress,
                  executor=make_executor(workers=args.workers), command=command,
                  log=lambda m: print("  " + m, flush=True))
        wall = time.perf_counter() - start
        note = f"{load_line()} at the end (the 2-core machine shared); features extracted in the train"
        path = doc.write_snapshot(f"train-size-{frames}", report / "results.json", command, wall, note=note,
                                  folder=args.snapshots, parameters={"frames_asked": frames},
                                  before=[{"command": render_command, "wall_s": round(render_s, 1),
                                           "date": time.strftime("%Y-%m-%d")}])
        print(f"[{frames} frames] rendered in {render_s:.0f} s, trained and tested in {wall:.0f} s: {path}; "
              f"{load_line()}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
