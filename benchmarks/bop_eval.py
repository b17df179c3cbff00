"""Our estimates scored by bop_toolkit's own eval_bop19_pose.py: AR, AR_VSD, AR_MSSD, AR_MSPD per method.

    python benchmarks/bop_eval.py --bop-toolkit /path/to/bop_toolkit --python /path/to/bop-venv/bin/python \\
        --out DIR [--classes cup,box] [--limit 48] [--methods template,n3m] [--protocol loco]

Steps (each a command of ours, run with this Python's spm and spm-data; every command is recorded):

1. ``spm-data render --class cup --class box --limit 48 --out DIR/render``
2. ``spm train DIR/render --methods template,n3m --runs 1 --out DIR/report --bop-results DIR/results``
   (each test frame's estimate in run 1: under loco every frame, by a model that never saw its class)
3. ``spm-data export bop DIR/render --out DIR/export --split test`` (with test_targets_bop19.json)
4. bop_toolkit copied to DIR/bop_toolkit and the dataset "spm" registered in the copy: a block
   appended to ``bop_toolkit_lib/dataset_params.py`` answers get_model_params / get_split_params for
   "spm" (obj_ids, symmetric objects, image size from DIR/datasets/spm/spm_dataset.json, LM's classic
   layout for the paths), and ``"spm": 15`` added to the ``vsd_deltas`` table of
   ``scripts/eval_bop19_pose.py`` (VSD's misalignment tolerance in mm, BOP's usual 15); the export
   copied to DIR/datasets/spm.
5. ``scripts/eval_bop19_pose.py --renderer_type vispy`` in the copy, in bop_toolkit's Python
   (--python, first on PATH: the script runs its helpers as "python"), BOP_PATH=DIR/datasets,
   results in DIR/results, scores in DIR/eval.

Prints AR, AR_VSD, AR_MSSD, AR_MSPD per method and writes DIR/bop_eval.json (date, machine,
commands, figures). Nothing of bop_toolkit is imported here.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bop_registration import DATASET, REGISTRATION, write_description  # noqa: E402

def run(cmd, log: list, env=None, cwd=None) -> str:
    """Run ``cmd``, recorded in ``log``; exit with its output's tail when it fails."""
    shown = " ".join(str(c) for c in cmd)
    print(f"$ {shown}", file=sys.stderr, flush=True)
    start = time.time()
    done = subprocess.run([str(c) for c in cmd], env=env, cwd=cwd, capture_output=True, text=True)
    log.append({"command": shown, "seconds": round(time.time() - start, 1), "exit": done.returncode})
    if done.returncode != 0:
        sys.exit(f"bop_eval: failed ({done.returncode}): {shown}\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}")
    return done.stdout


def register(toolkit: Path, out: Path, export: Path, split: str) -> tuple[Path, Path]:
    """(the bop_toolkit copy, its datasets folder) with "spm" registered and the export in it."""
    copy = out / "bop_toolkit"
    shutil.rmtree(copy, ignore_errors=True)
    shutil.copytree(toolkit, copy, ignore=shutil.ignore_patterns(".git", "__pycache__", "*.egg-info"))
    params = copy / "bop_toolkit_lib" / "dataset_params.py"
    params.write_text(params.read_text() + REGISTRATION)
    script = copy / "scripts" / "eval_bop19_pose.py"   # VSD's delta (mm) is per dataset: BOP's usual 15
    text = script.read_text()
    if '"vsd_deltas": {' not in text:
        sys.exit(f"bop_eval: {script} has no vsd_deltas table to add 'spm' to; another bop_toolkit version?")
    script.write_text(text.replace('"vsd_deltas": {', '"vsd_deltas": {"spm": 15, ', 1))
    datasets = out / "datasets"
    shutil.rmtree(datasets, ignore_errors=True)
    shutil.copytree(export, datasets / DATASET)
    write_description(export, datasets / DATASET, [split])
    return copy, datasets


def scores(eval_dir: Path, csv: Path) -> dict:
    """AR, AR_VSD, AR_MSSD, AR_MSPD of one results file, from bop_toolkit's scores_bop19.json."""
    payload = json.loads((eval_dir / csv.stem / "scores_bop19.json").read_text())
    return {"AR": payload["bop19_average_recall"], "AR_VSD": payload["bop19_average_recall_vsd"],
            "AR_MSSD": payload["bop19_average_recall_mssd"], "AR_MSPD": payload["bop19_average_recall_mspd"],
            "time_per_image_s": _number(payload.get("bop19_average_time_per_image"))}


def _number(value):
    """A JSON number, or None for bop_toolkit's NaN (no time measured, or no estimate)."""
    return None if value is None or value != value or value < 0 else float(value)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bop-toolkit", required=True, type=Path, help="bop_toolkit checkout (copied, never changed)")
    ap.add_argument("--python", required=True, help="the Python bop_toolkit is installed in")
    ap.add_argument("--out", required=True, type=Path, help="work folder (made)")
    ap.add_argument("--classes", default="cup,box")
    ap.add_argument("--limit", type=int, default=48, help="frames per class")
    ap.add_argument("--methods", default="template,n3m")
    ap.add_argument("--protocol", default="loco")
    ap.add_argument("--reuse", action="store_true", help="keep DIR's render, results and export (steps 1-3)")
    args = ap.parse_args(argv)
    out = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    bin_dir = Path(sys.executable).parent
    env = dict(os.environ, PYOPENGL_PLATFORM="egl")
    log: list = []
    render, results, export = out / "render", out / "results", out / "export"
    reuse = args.reuse and export.is_dir() and results.is_dir()
    for p in ((out / "eval",) if reuse else (render, results, export, out / "report", out / "eval")):
        shutil.rmtree(p, ignore_errors=True)
    classes = [c for c in args.classes.split(",") if c]
    steps = [[bin_dir / "spm-data", "render", *[a for c in classes for a in ("--class", c)], "--limit", args.limit,
              "--out", render],
             [bin_dir / "spm", "train", render, "--methods", args.methods, "--runs", 1, "--protocol", args.protocol,
              "--out", out / "report", "--bop-results", results],
             [bin_dir / "spm-data", "export", "bop", render, "--out", export, "--split", "test"]]
    earlier = (json.loads((out / "bop_eval.json").read_text())["commands"][:3]
               if reuse and (out / "bop_eval.json").is_file() else [])
    for step in steps:
        if reuse:
            log.append(earlier.pop(0) if earlier else {"command": " ".join(map(str, step)), "reused": True})
        else:
            run(step, log, env)
    copy, datasets = register(args.bop_toolkit.resolve(), out, export, "test")
    log.append({"command": f"copy {args.bop_toolkit} to {copy}; append the 'spm' registration to "
                           "bop_toolkit_lib/dataset_params.py; copy the export to " + str(datasets / DATASET)})
    tk_env = dict(env, PYTHONPATH=str(copy), BOP_PATH=str(datasets), BOP_RESULTS_PATH=str(results),
                  BOP_EVAL_PATH=str(out / "eval"), PATH=f"{Path(args.python).parent}{os.pathsep}{env['PATH']}")
    tk_env.setdefault("EGL_PLATFORM", "surfaceless")
    figures = {}
    for csv in sorted(results.glob("*.csv")):
        method = csv.name.split("_")[0]
        rows = len(csv.read_text().splitlines()) - 1
        run([args.python, copy / "scripts" / "eval_bop19_pose.py", "--renderer_type", "vispy",
             "--result_filenames", csv.name, "--results_path", results, "--eval_path", out / "eval",
             "--num_workers", 1], log, tk_env, cwd=copy)
        figures[method] = {**scores(out / "eval", csv), "estimates": rows}
    targets = len(json.loads((export / "test_targets_bop19.json").read_text()))
    print(f"{'method':<12}{'AR':>8}{'AR_VSD':>8}{'AR_MSSD':>9}{'AR_MSPD':>9}{'estimates':>11}  (of {targets} targets)")
    for m, f in figures.items():
        print(f"{m:<12}{f['AR']:>8.3f}{f['AR_VSD']:>8.3f}{f['AR_MSSD']:>9.3f}{f['AR_MSPD']:>9.3f}{f['estimates']:>11}")
    payload = {"date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
               "machine": {"host": platform.node(), "platform": platform.platform(), "cpus": os.cpu_count(),
                           "python": platform.python_version()},
               "bop_toolkit": str(args.bop_toolkit), "targets": targets, "protocol": args.protocol,
               "commands": log, "figures": figures}
    (out / "bop_eval.json").write_text(json.dumps(payload, indent=1))
    print(f"wrote {out / 'bop_eval.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
