"""What process isolation costs: `spm train` as it runs (each split's methods in a fresh process)
against a stand-in that runs the very same child code without a new process.

    python benchmarks/isolation_cost.py SHARDS --out DIR [--protocols loco,views,instances]
        [--runs 3] [--workers 2] [--methods spm,knn1,knn3,pca,ls,template,chance] [--rounds 2]
        [--order isolated-first|in-process-first] [--measure docs/results/measures/isolation-cost.json]

Times the library call behind `spm train SHARDS --protocol P --runs R --workers W` (as
benchmarks/protocol_times.py does, its ``timed_train``) for each protocol, ROUNDS times each way,
alternating (isolated, in-process, isolated, in-process with the default order), into
DIR/WAY-ROUND/P. The default methods are the seven other than N3M, SMM and the CNN.

- isolated: as `spm train` runs: spm_model/bench/isolation.py's ``fresh_process``, a child
  process per split (and a spare started beside it).
- in-process: a stand-in used by this script only: every job the executor hands to a worker goes
  through :func:`with_stand_in`, which puts :class:`ThreadChild` in place of ``fresh_process``
  in that worker for the job: spm_model/bench/isolated_child.py's ``serve`` on one end of a pipe,
  in a thread of the worker, fed and read by the same code (fitting._ask) over the same pipe
  messages.

The workers of both ways start with the methods' environment (isolation.method_environment: the
BLAS and SIMD code a method's process gets), so that the stand-in's estimates are the same bits
and the scoring in the workers runs the same code both ways (with the workers' own SIMD code the
template method's median error differed by 3e-14); that needs spawned workers: --workers 2 or more.

Every run's results.json summaries must equal the first run's (protocol_times' ``differences``,
both ways), else it exits 1 naming the first difference. Prints per protocol and in total: each
run's wall seconds with the 1-minute load average at its start and end, the medians each way and
the ratio isolated / in-process (the target: at most 1.10). --measure writes the figures with a
``made`` block (the command, date, machine, every run's loads) for scripts/results_doc.py. The
feature cache is filled (or checked) once before the first timed run; wall times include loading
it, as protocol_times' do. Progress on stderr, as in protocol_times.
"""

from __future__ import annotations

import argparse
import functools
import importlib.util
import os
import shlex
import statistics
import sys
import threading
import time
from multiprocessing import Pipe
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.append(str(ROOT / "benchmarks"))   # protocol_times, after every package: its names shadow none

from spm_data.errors import SpmError  # noqa: E402
from spm_data.io.files import write_json_atomic  # noqa: E402
from spm_data.jobs.executor import LocalExecutor, environment  # noqa: E402
from spm_model.bench import fitting  # noqa: E402
from spm_model.bench.feature_cache import load_features  # noqa: E402
from spm_model.bench.isolated_child import Closed, serve  # noqa: E402
from spm_model.bench.isolation import READY, EstimatorProcess, method_environment  # noqa: E402
from protocol_times import CompareError, differences, timed_train  # noqa: E402

SEVEN = "spm,knn1,knn3,pca,ls,template,chance"
TARGET_RATIO = 1.10
WAYS = ("isolated", "in-process")


class _ThreadAsProcess(threading.Thread):
    """What EstimatorProcess asks of its ``proc`` (poll, wait, kill), for a thread."""

    def poll(self):
        return None if self.is_alive() else 0

    def wait(self, timeout=None):
        self.join(timeout)
        return 0

    def kill(self):
        """A thread cannot be killed; only a message unfinished for MESSAGE_SECONDS asks it."""


def _serve_here(down, up) -> None:
    """isolated_child.child_main's work without what belongs to a process (Ctrl-C, the parent
    watch, os._exit): READY, then ``serve`` on one BLAS thread until the parent closes."""
    from threadpoolctl import threadpool_limits

    try:
        up.send_bytes(READY)
        with threadpool_limits(limits=1, user_api="blas"):
            serve(down, up)
    except (EOFError, OSError, Closed):
        pass
    finally:
        down.close()
        up.close()


class ThreadChild(EstimatorProcess):
    """EstimatorProcess's parent end, its child's ``serve`` in a thread of this process."""

    def __init__(self):
        down_r, self.down = Pipe(duplex=False)   # parent -> thread
        self.up, up_w = Pipe(duplex=False)       # thread -> parent
        self.started_as = None
        self.ready = False
        self.proc = _ThreadAsProcess(target=_serve_here, args=(down_r, up_w), daemon=True)
        self.proc.start()


def with_stand_in(fn, job, report):
    """``fn(job, report)`` with ThreadChild in place of fitting.fresh_process (in this worker)."""
    before = fitting.fresh_process
    fitting.fresh_process = ThreadChild
    try:
        return fn(job, report)
    finally:
        fitting.fresh_process = before


class StandInExecutor(LocalExecutor):
    """LocalExecutor whose jobs run with_stand_in (a module-level partial: it reaches spawned workers)."""

    def run(self, fn, jobs, **kwargs):
        return super().run(functools.partial(with_stand_in, fn), jobs, **kwargs)


def executor_of(way: str, workers: int) -> LocalExecutor:
    return LocalExecutor(workers=workers) if way == "isolated" else StandInExecutor(workers=workers)


def timed_run(way: str, args, folder: Path, builtins) -> dict:
    """{protocol: {"wall_s", "load_start", "load_end"}} of one run of every protocol, ``way``."""
    out = {}
    with environment(method_environment()):   # both ways' workers start with it (module docstring)
        for protocol in args.protocols:
            load = os.getloadavg()[0]
            wall = timed_train(args.shards, folder / protocol, protocol, args.runs, builtins,
                               executor_of(way, args.workers))
            out[protocol] = {"wall_s": round(wall, 1), "load_start": round(load, 2),
                             "load_end": round(os.getloadavg()[0], 2)}
            print(f"{way} {folder.name} {protocol}: {wall:.1f} s (load {load:.2f} -> {os.getloadavg()[0]:.2f})",
                  flush=True)
    return out


def first_difference(a: Path, b: Path) -> str | None:
    """The first figure of the results.json summaries that differs between two runs' folders."""
    for x, y in ((a, b), (b, a)):
        for protocol, method, worst, key in differences(x, y):
            if method is None:
                return f"{protocol}: in {x} but not in {y}"
            if not worst == 0:   # nan (missing) differs too
                return f"{protocol} {method}: {key} differs by {worst:.3g} between {x} and {y}"
    return None


def figures(runs: dict, protocols: list) -> dict:
    """Per protocol and in total: each way's walls (in round order), medians and the ratio."""
    out = {}
    for part in [*protocols, "total"]:
        walls = {way: [round(sum(r[p]["wall_s"] for p in protocols) if part == "total" else r[part]["wall_s"], 1)
                       for (w, _), r in runs.items() if w == way] for way in WAYS}
        medians = {way: statistics.median(v) for way, v in walls.items()}
        out[part] = {"isolated_s": walls["isolated"], "in_process_s": walls["in-process"],
                     "isolated_median_s": round(medians["isolated"], 1),
                     "in_process_median_s": round(medians["in-process"], 1),
                     "ratio": round(medians["isolated"] / medians["in-process"], 3)}
    return out


def _made_block(command: str, wall_s: float, parameters: dict) -> dict:
    spec = importlib.util.spec_from_file_location("results_doc", ROOT / "scripts" / "results_doc.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.made_block(command, wall_s, parameters=parameters)


def parse(argv):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("shards", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--protocols", default="loco,views,instances", type=lambda s: s.split(","))
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--methods", default=SEVEN, help=f"comma-separated built-in methods (default {SEVEN})")
    parser.add_argument("--rounds", type=int, default=2, help="runs each way (default 2)")
    parser.add_argument("--order", choices=("isolated-first", "in-process-first"), default="isolated-first")
    parser.add_argument("--measure", type=Path, help="write the figures and how they were made to this JSON")
    args = parser.parse_args(argv)
    if args.workers < 2:
        parser.error("--workers must be 2 or more: the stand-in's workers are spawned with the methods' "
                     "environment, as the isolated way's method processes are")
    if args.rounds < 1:
        parser.error("--rounds must be 1 or more")
    return args


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parse(argv)
    builtins = args.methods.split(",")
    order = WAYS if args.order == "isolated-first" else WAYS[::-1]
    start = time.monotonic()
    try:
        frames = len(load_features(args.shards, executor=LocalExecutor(workers=args.workers)))   # untimed
        runs = {}
        for n in range(1, args.rounds + 1):
            for way in order:
                runs[way, n] = timed_run(way, args, args.out / f"{way}-{n}", builtins)
        folders = [args.out / f"{way}-{n}" for way, n in runs]
        why = next((d for f in folders[1:] if (d := first_difference(folders[0], f))), None)
    except (SpmError, CompareError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    if why is not None:
        print(f"error: the two ways' results differ: {why}", file=sys.stderr)
        return 1
    found = figures(runs, args.protocols)
    for part, f in found.items():
        print(f"{part}: isolated {' '.join(f'{w:.1f}' for w in f['isolated_s'])} s (median "
              f"{f['isolated_median_s']:.1f}), in-process {' '.join(f'{w:.1f}' for w in f['in_process_s'])} s "
              f"(median {f['in_process_median_s']:.1f}): ratio {f['ratio']:.3f} (target <= {TARGET_RATIO:.2f})")
    print(f"results.json summaries identical in all {len(runs)} runs; {os.cpu_count()} CPUs")
    if args.measure:
        parameters = {"protocols": ",".join(args.protocols), "runs": args.runs, "workers": args.workers,
                      "methods": args.methods, "rounds": args.rounds, "order": args.order}
        made = _made_block(shlex.join(["python", "benchmarks/isolation_cost.py", *argv]), time.monotonic() - start,
                           parameters)
        made["loads"] = [{"way": way, "round": n, "protocol": p, "start": r[p]["load_start"], "end": r[p]["load_end"]}
                         for (way, n), r in runs.items() for p in args.protocols]
        summary = {"frames": frames, "target_ratio": TARGET_RATIO, "identical": True,
                   "protocols": {p: found[p] for p in args.protocols}, "total": found["total"]}
        args.measure.parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(args.measure, {"summary": summary, "made": made}, sort_keys=False)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
