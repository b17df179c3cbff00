"""How long the benchmark takes: `spm train` under each protocol, features cached.

    python benchmarks/protocol_times.py SHARDS --out DIR [--protocols loco,views,instances]
        [--runs 3] [--workers 2] [--methods spm,knn1,...]
    python benchmarks/protocol_times.py --compare DIR_A DIR_B

Runs the library call behind `spm train SHARDS --protocol P --runs R --workers W` for
each protocol into DIR/P and prints its wall time (loading the cached features, the
runs and splits, the final models and the report), then the total against the
issue's targets: all three protocols <= 10 min, loco <= 5 min (default dataset:
`spm-data render --all --renderer pyrender`, features extracted once beforehand, e.g.
by a first `spm train`). ``--compare`` prints, per protocol and method, the largest
difference between two such folders' results.json summaries (0 when a change is
exact). Progress on stderr (a bar on a terminal, a line every
$SPM_PROGRESS_EVERY s, default 10, elsewhere): each step of spm train.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from spm_data.jobs.progress import stage  # noqa: E402
from spm_data.jobs.executor import LocalExecutor  # noqa: E402
from spm_model.pipelines.train import train  # noqa: E402

TARGETS = {"total": 600.0, "loco": 300.0}


def leaves(value, prefix=""):
    """{dotted key: number} of every numeric leaf of a JSON value."""
    if isinstance(value, dict):
        return {k: v for key, item in value.items() for k, v in leaves(item, f"{prefix}{key}.").items()}
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return {prefix.rstrip("."): float(value)}
    return {}


class CompareError(Exception):
    """An input --compare cannot read (main prints it as one ``error:`` line)."""


def _methods(path: Path) -> dict:
    """results.json's summary.methods; CompareError saying why not."""
    try:
        methods = json.loads(path.read_text())["summary"]["methods"]
        if not isinstance(methods, dict):
            raise TypeError(f"summary.methods is {type(methods).__name__}, not a table")
        return methods
    except OSError as exc:
        raise CompareError(f"{path}: cannot read it ({exc.strerror or exc})") from None
    except (ValueError, KeyError, TypeError) as exc:
        detail = f"no {exc}" if isinstance(exc, KeyError) else f"{type(exc).__name__}: {exc}"
        raise CompareError(f"{path}: not a results.json spm train wrote ({detail}); give two --out folders "
                           "of this script") from None


def differences(a: Path, b: Path) -> list:
    """(protocol, method, largest difference, its key) for every method of every protocol folder
    of ``a`` against ``b``'s (method None: the protocol is missing in ``b``; a method or figure
    missing in ``b`` differs by nan). CompareError when a folder or results.json cannot be read."""
    for folder in (a, b):
        if not folder.is_dir():
            raise CompareError(f"{folder}: no such folder; give two --out folders of this script")
    rows = []
    for folder in sorted(p for p in a.iterdir() if (p / "results.json").exists()):
        other = b / folder.name / "results.json"
        if not other.exists():
            rows.append((folder.name, None, float("nan"), ""))
            continue
        A, B = _methods(folder / "results.json"), _methods(other)
        for method in A:
            la, lb = leaves(A[method]), leaves(B.get(method, {}))
            keys = set(la) | set(lb)
            worst = max((abs(la.get(k, float("nan")) - lb.get(k, float("nan"))), k) for k in keys) if keys else (0, "")
            rows.append((folder.name, method, *worst))
    return rows


def compare(a: Path, b: Path) -> None:
    for protocol, method, worst, key in differences(a, b):
        print(f"{protocol}: missing in {b}" if method is None
              else f"{protocol} {method}: largest difference {worst:.3g} ({key})")


def timed_train(shards: Path, out: Path, protocol: str, runs: int, builtins, executor) -> float:
    """Wall seconds of the library call behind `spm train SHARDS --protocol P --runs R` into ``out``."""
    t0 = time.perf_counter()
    with stage(f"protocol_times: spm train {shards} --protocol {protocol}") as progress:
        train(shards, out, protocol=protocol, runs=runs, builtins=builtins, executor=executor, progress=progress)
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("shards", type=Path, nargs="?")
    parser.add_argument("--out", type=Path)
    parser.add_argument("--protocols", default="loco,views,instances")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--methods", help="comma-separated built-in methods (default all)")
    parser.add_argument("--compare", type=Path, nargs=2)
    args = parser.parse_args()
    if args.compare:
        try:
            return compare(*args.compare)
        except CompareError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 1
    if args.shards is None or args.out is None:
        parser.error("give SHARDS and --out")
    builtins = args.methods.split(",") if args.methods else None
    load = os.getloadavg()[0]
    times = {}
    for protocol in args.protocols.split(","):
        times[protocol] = timed_train(args.shards, args.out / protocol, protocol, args.runs, builtins,
                                      LocalExecutor(workers=args.workers))
        print(f"{protocol}: {times[protocol]:.0f} s ({args.runs} runs, {args.workers} workers, "
              f"methods {args.methods or 'all'})", flush=True)
    total = sum(times.values())
    print(f"total {total:.0f} s = {total / 60:.1f} min (target {TARGETS['total'] / 60:.0f} min); "
          + (f"loco {times['loco'] / 60:.1f} min (target {TARGETS['loco'] / 60:.0f} min); " if "loco" in times else "")
          + f"load average {load:.1f} at the start, {os.getloadavg()[0]:.1f} at the end; {os.cpu_count()} CPUs")


if __name__ == "__main__":
    sys.exit(main())
