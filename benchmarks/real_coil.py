"""Every method on real turntable images: a COIL-20 or COIL-100 set in its original layout
(``obj{K}__{N}.png``; the folder you downloaded: nothing is shipped or downloaded here), imported
with ``spm-data import coil20|coil100`` and benchmarked under two protocols, every built-in
method, 3 runs each:

- ``views``: a seeded 20% of the (object, view) pairs held out per run, the rest trains;
- ``interleaved``: train on the 10-degree views, test on the 5-degree views between them.

Prints one table per protocol (coverage, features found, ±5° with σ and its range over runs,
the declined methods with their reasons) beside the paper's Table 2 (KNN on SPM's vectors:
82.6-95.5% within ±5°, on COIL-100, CVL and renders together), and writes the same as markdown to OUT/real_coil.md with
the date, machine and
commands; the reports are in OUT/report-views and OUT/report-interleaved.

    python benchmarks/real_coil.py coil-20-proc/ --out out/real-coil20
    python scripts/coil_from_mat.py COIL20.mat --out coil20-32/ && python benchmarks/real_coil.py coil20-32/
    spm-data import coil20 coil20-32/ --out coil20-imp/ && python benchmarks/real_coil.py coil20-imp/   # imported

COIL-20's processed set is ``coil-20-proc.zip`` from Columbia's CAVE pages (128 x 128 grey);
copies of it at 32 x 32 circulate as ``COIL20.mat`` in public repositories, which
scripts/coil_from_mat.py writes out in the original layout. The import and each spm train
report their progress on stderr (a bar on a terminal, a line every $SPM_PROGRESS_EVERY s, default
10, elsewhere).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import sys
import time
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from spm_data.jobs.progress import Progress  # noqa: E402
from spm_data.errors import SpmError  # noqa: E402
from spm_data.formats.coil100 import NAME, import_coil20, import_coil100, list_members  # noqa: E402
from spm_data.io.files import atomic_file  # noqa: E402
from spm_data.io.shards import list_shards, read_attrs  # noqa: E402
from spm_data.jobs import make_executor  # noqa: E402
from spm_model.pipelines.train import train  # noqa: E402
from spm_model.methods.registry import METHOD_NAMES  # noqa: E402

PAPER_TABLE2 = ("The paper's Table 2, KNN on SPM's vectors: 82.6-94.7% within ±5° per class (K=1), 82.8-95.5% (K=3), "
                "its six classes trained on COIL-100, CVL and renders together, leave-one-out over classes")
PROTOCOLS = ("views", "interleaved")


TAKES = ("give the COIL-20/COIL-100 images in their original layout (obj{K}__{N}.png: the folder or zip you "
         "downloaded, or what scripts/coil_from_mat.py wrote), or the folder spm-data import coil20|coil100 wrote")


def imported_layout(folder) -> str | None:
    """"coil20"/"coil100" when ``folder`` holds shards spm-data import coil20|coil100 wrote; None
    when it holds no shards; SpmError for shards of anything else."""
    shards = list_shards(folder) if Path(folder).is_dir() else []
    if not shards:
        return None
    kind = read_attrs(shards[0]).get("import")
    if kind not in ("coil20", "coil100"):
        raise SpmError(f"{folder}: its shards are {'imported from ' + kind if kind else 'renders'}, not COIL; "
                       + TAKES)
    return kind


def layout_of(folder) -> str:
    """"coil100" when files are numbered by angle (some number above 71), else "coil20"."""
    try:
        refs = list_members(folder)
    except SpmError:
        raise SpmError(f"{folder}: not found or not a folder, zip or tar; " + TAKES) from None
    numbers = [int(m.group(2)) for ref in refs if (m := NAME.search(ref.split("::")[-1]))]
    if not numbers:
        raise SpmError(f"{folder}: no obj{{K}}__{{N}}.png files and no shards; " + TAKES)
    return "coil100" if max(numbers) > 71 else "coil20"


def stamp(message: str, start: float) -> None:
    print(f"[{time.monotonic() - start:7.1f} s] {message}", flush=True)


def method_rows(report: Path) -> tuple[list, dict]:
    """Rows (method, coverage %, features, ±5° %, σ, min-max over runs) and the declined methods."""
    payload = json.loads((report / "results.json").read_text())
    summary, runs = payload["summary"], payload["evaluation"]["runs"]
    rows = []
    entries = {**summary["methods"], **({"chance": summary["chance"]} if summary["chance"] else {})}
    for m, s in entries.items():
        per_run = [r["overall"][m]["success_tol5"] for r in runs]
        featured = s.get("featured")
        rows.append([METHOD_NAMES.get(m, m), _fmt(s["coverage"]),
                     "–" if featured is None else f"{featured}/{s['frames']}", _fmt(s["success_tol5"]),
                     _fmt(s["std"]["success_tol5"]), f"{_fmt(min(per_run))}–{_fmt(max(per_run))}"])
    return rows, summary.get("declined", {})


def _fmt(value) -> str:
    return "–" if value is None else f"{value:.1f}"


def markdown_table(rows: list) -> list[str]:
    header = ["Method", "Coverage %", "Features (test frames)", "±5° azimuth %", "σ", "runs min–max"]
    return (["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
            + ["| " + " | ".join(r) + " |" for r in rows])


def main(argv=None) -> int:
    try:
        return run(argv)
    except SpmError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1


def run(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", help="a COIL-20 or COIL-100 folder (or zip) in the original layout, or the "
                                       "folder spm-data import coil20|coil100 wrote")
    parser.add_argument("--out", default="out/real-coil", help="where the shards, reports and tables go")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--layout", choices=("auto", "coil20", "coil100"), default="auto")
    parser.add_argument("--methods", default=None, metavar="NAME,...",
                        help="built-in methods (default all), as spm train --methods: e.g. cnn,chance to add one "
                             "method's rows to an earlier run's (the same import, seeds and splits)")
    args = parser.parse_args(argv)
    methods = None if args.methods is None else [m.strip() for m in args.methods.split(",") if m.strip()]
    also = "" if methods is None else f" --methods {','.join(methods)}"
    start = time.monotonic()
    out = Path(args.out)
    imported = imported_layout(args.folder)
    if imported:
        layout, shards = imported, Path(args.folder)
        stamp(f"using the {layout} shards in {shards} (imported already)", start)
    else:
        layout = layout_of(args.folder) if args.layout == "auto" else args.layout
        shards = out / "shards"
        stamp(f"importing {args.folder} as {layout} into {shards}", start)
        with Progress("image", f"importing {layout}") as progress:
            summary, problems = (import_coil20 if layout == "coil20" else import_coil100)(args.folder, shards,
                                                                                         progress=progress)
        stamp(f"{summary.frames} frames imported ({len(problems)} problems listed by the importer)", start)
    lines = [f"# Real images: {layout} from `{args.folder}`", "",
             f"{datetime.date.today().isoformat()}, {platform.node()} ({os.cpu_count()} cores), "
             f"`python benchmarks/real_coil.py {' '.join(argv if argv is not None else sys.argv[1:])}`; "
             f"{args.runs} runs per protocol, {', '.join(methods) if methods else 'every built-in method'}.", "",
             PAPER_TABLE2 + ".", ""]
    for protocol in PROTOCOLS:
        report = out / f"report-{protocol}"
        stamp(f"spm train {shards} --protocol {protocol} --runs {args.runs} --workers {args.workers}{also} "
              f"--out {report}", start)
        with Progress() as progress:
            train(shards, report, protocol=protocol, runs=args.runs, executor=make_executor(workers=args.workers),
                  log=lambda m: stamp(m, start), progress=progress, builtins=methods,
                  command=f"spm train {shards} --protocol {protocol} --runs {args.runs} --workers {args.workers}"
                          f"{also} --out {report}")
        rows, declined = method_rows(report)
        section = [f"## {protocol}", "", f"Command: `spm train {shards} --protocol {protocol} --runs {args.runs}"
                   f"{also} --out {report}`", ""] + markdown_table(rows) + [""]
        section += [f"- {METHOD_NAMES.get(m, m)} declined ({d['splits']} of {d['of']} splits): {d['reason']}"
                    for m, d in declined.items()] + [""]
        print("\n".join(section), flush=True)
        lines += section
    with atomic_file(out / "real_coil.md") as tmp:
        tmp.write_text("\n".join(lines))
    stamp(f"tables: {out / 'real_coil.md'}", start)
    return 0


if __name__ == "__main__":
    sys.exit(main())
