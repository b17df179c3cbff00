"""Interruptions at random points, concurrent runs, fuzzed specs and shards."""

import os
import random
import signal
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.helpers import reaped, wait_for
from spm_data.errors import SpmError
from spm_data.io.locking import LOCK_NAME, lock_owner
from spm_data.pipelines.render_jobs import load_run_specs, render_dataset
from spm_data.io.shards import list_shards, read_manifest, read_shard, write_shard
from spm_data.core.specs import parse_spec

pytestmark = pytest.mark.slow  # renders killed and resumed at random points (fuzzing)

# 2 instances x 108 views (azimuth every 10 degrees at 3 elevations) at 48 x 48: 216 frames.
SPEC = ('class = "cup"\n[mesh]\ninstances = 2\n[camera]\nazimuth = [0, 350, 10]\nelevation = [0, 20, 10]\n'
        '[image]\nwidth = 48\nheight = 48\n[render]\nrenderer = "{renderer}"\nframes_per_shard = {per}\n'
        '[render.blender]\nsamples = 2\n')
CLI = [sys.executable, "-c", "import cli; cli.data_cli()"]


def arrays(folder):
    return {p.name: read_shard(p, ["rgb", "depth", "mask", "pose"]) for p in list_shards(folder)}


def assert_same(a, b):
    """Geometry and labels bit for bit. RGB too, except that Mesa's rasteriser was seen to
    put one channel of one pixel one level apart in about 1 run in 10 (docs/reliability.md):
    at most one level, in at most 1e-5 of the values."""
    assert a.keys() == b.keys()
    for name in a:
        for k in a[name]:
            if k == "rgb":
                diff = np.abs(a[name][k].astype(int) - b[name][k].astype(int))
                assert diff.max() <= 1 and (diff > 0).mean() <= 1e-5, (name, int(diff.max()), int((diff > 0).sum()))
            else:
                np.testing.assert_array_equal(a[name][k], b[name][k], err_msg=f"{name}:{k}")


def assert_clean(folder):
    # No .spm.lock* either: the lock, its guard (made when a stale lock is taken over), a temporary record.
    leftovers = [p.name for p in folder.iterdir() if p.name.endswith(".partial") or p.name.startswith(LOCK_NAME)]
    assert leftovers == []
    assert [e["file"] for e in read_manifest(folder)["shards"]] == [p.name for p in list_shards(folder)]


def progress(folder):
    """(complete shards, partial shards being written) in ``folder`` now."""
    if not folder.is_dir():
        return 0, 0
    return len(list_shards(folder)), len(list(folder.glob(".*.partial")))


def interrupt(cmd, folder, sig, point):
    """Run ``cmd`` and send it ``sig`` at ``point`` = (k, mid): once k shards are complete
    and, if mid, a shard is being written (a ``.partial`` exists). A state, not a time, so
    the kill lands at the same stage of the run however loaded the machine is. If the run
    ends first, it is left alone: its folder is as valid a starting point for a resume."""
    k, mid = point
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL), start_new_session=True)
    with reaped(proc, kill=lambda: os.killpg(proc.pid, signal.SIGKILL)):
        def reached():
            done, partial = progress(folder)
            return done >= k and (partial > 0 or not mid)

        # Short polls: a shard's .partial lives for tens of milliseconds.
        wait_for(lambda: proc.poll() is not None or reached(), f"{k} complete shards{' and a partial' * mid}",
                 interval=0.01)
        if sig == signal.SIGKILL:
            try:
                os.killpg(proc.pid, signal.SIGKILL)  # the CLI and its workers, as a killed terminal would
            except ProcessLookupError:
                pass  # the run had ended, workers and all
        else:
            proc.send_signal(sig)  # a no-op if it has ended
        out, _ = proc.communicate(timeout=120)
    return proc.returncode, out


def interruption_points(rng, shards, count, workers=1):
    """``count`` random points in a run of ``shards`` shards (see interrupt), alternately
    mid-shard and between shards (which first is random). At most shards - 1 - workers
    complete: with every worker busy, at least one shard is still to start, so the
    signal (almost always) lands mid-run rather than in the run's final bookkeeping."""
    first = rng.random() < 0.5
    mids = [first != (i % 2 == 1) for i in range(count)]
    return [(rng.randint(0 if mid else 1, shards - 1 - workers), mid) for mid in mids]


@pytest.mark.parametrize("renderer, per, workers, seeds", [("pyrender", 12, 1, (1, 2, 3)), ("pyrender", 12, 2, (4,)),
                                                           ("blender", 12, 2, (5,))])
def test_killed_and_interrupted_renders_resume_to_the_same_arrays(tmp_path, renderer, per, workers, seeds):
    spec = tmp_path / "cup.toml"
    spec.write_text(SPEC.format(renderer=renderer, per=per))
    base = CLI + ["render", "--spec", str(spec), "--workers", str(workers)]
    if renderer == "blender":
        base += ["--limit", "48"]
    reference = tmp_path / "reference"
    assert subprocess.run(base + ["--out", str(reference)], capture_output=True, timeout=300).returncode == 0
    shards = len(list_shards(reference))
    for seed in seeds:
        rng = random.Random(seed)
        sigs = (signal.SIGKILL, signal.SIGINT)
        for sig, point in zip(sigs, interruption_points(rng, shards, len(sigs), workers)):
            out = tmp_path / f"run-{seed}-{int(sig)}"
            code, text = interrupt(base + ["--out", str(out)], out, sig, point)
            assert "Traceback" not in text, (point, text)
            if sig == signal.SIGKILL:
                assert code in (0, -signal.SIGKILL), (point, code, text)  # 0: it had ended
            if sig == signal.SIGINT and code == 130:
                assert "run the same command again to resume" in text
            again = subprocess.run(base + ["--out", str(out)], capture_output=True, text=True, timeout=300)
            assert again.returncode == 0, (point, again.stdout + again.stderr)
            assert_clean(out)
            assert_same(arrays(out), arrays(reference))


def test_killed_occlude_resumes_to_the_same_bytes(tmp_path):
    spec = tmp_path / "cup.toml"
    spec.write_text(SPEC.format(renderer="pyrender", per=16))
    render_dataset(load_run_specs(spec_files=[spec]), tmp_path / "r")
    base = CLI + ["occlude", str(tmp_path / "r"), "--copies", "4", "--seed", "9"]
    assert subprocess.run(base + ["--out", str(tmp_path / "ref")], capture_output=True).returncode == 0
    shards = len(list_shards(tmp_path / "ref"))
    # Killed while writing the first shard, then at a random later point.
    for k, mid in [(0, True)] + interruption_points(random.Random(9), shards, 1):
        out = tmp_path / f"occ-{k}-{int(mid)}"
        interrupt(base + ["--out", str(out)], out, signal.SIGKILL, (k, mid))
        assert subprocess.run(base + ["--out", str(out)], capture_output=True).returncode == 0
        assert_clean(out)
        ref = {p.name: p.read_bytes() for p in list_shards(tmp_path / "ref")}
        got = {p.name: p.read_bytes() for p in list_shards(out)}
        assert got == ref


def test_a_second_run_on_the_same_folder_is_refused_and_stale_locks_are_taken(tmp_path, small_specs_dir):
    out = tmp_path / "out"
    out.mkdir()
    holder = subprocess.Popen(["sleep", "30"])
    try:
        (out / LOCK_NAME).write_text(f"{holder.pid}\n")
        with pytest.raises(SpmError, match=rf"another run is writing to {out}/ \(pid {holder.pid} on host "):
            render_dataset(load_run_specs(["cup"], specs_dir=small_specs_dir), out, limit=2)
        assert list_shards(out) == []
    finally:
        holder.kill()
        holder.wait()
    # The holder is gone: its lock is stale and the next run takes it.
    summary = render_dataset(load_run_specs(["cup"], specs_dir=small_specs_dir), out, limit=2)
    assert summary.frames == 2 and [p.name for p in out.glob(".spm.lock*")] == []   # nor its guard


def test_two_concurrent_cli_runs_do_not_corrupt_a_folder(tmp_path):
    spec = tmp_path / "cup.toml"
    spec.write_text(SPEC.format(renderer="pyrender", per=24))
    out = tmp_path / "out"
    cmd = CLI + ["render", "--spec", str(spec), "--out", str(out)]
    first = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lock = out / LOCK_NAME

    def first_holds_the_lock():
        owner = lock_owner(out)  # the lock file is made with its owner in one step
        return owner is not None and owner.pid == first.pid

    with reaped(first):
        # Once the first run holds the lock, freeze it there: the second one meets it mid-run,
        # however fast or slow the machine.
        wait_for(first_holds_the_lock, f"the first run to take {lock}", interval=0.01, proc=first)
        first.send_signal(signal.SIGSTOP)
        try:
            second = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
        finally:
            first.send_signal(signal.SIGCONT)
        output, _ = first.communicate(timeout=300)
    assert second.returncode == 1, second.stdout + second.stderr
    assert "another run is writing to" in second.stderr and "(pid " in second.stderr
    assert first.returncode == 0, output
    assert_clean(out)


toml_values = st.recursive(
    st.one_of(st.booleans(), st.integers(-10**6, 10**6), st.floats(allow_nan=True), st.text(max_size=8)),
    lambda children: st.lists(children, max_size=4), max_leaves=8)
KEYS = ["class", "seed", "mesh.instances", "mesh.size", "mesh.source", "camera.azimuth", "camera.elevation",
        "camera.distances", "image.width", "image.fov", "lighting.lights", "render.renderer",
        "render.frames_per_shard", "render.blender.samples", "background.kind", "background.color", "bogus"]


def to_toml(path, value):
    import json

    def literal(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, float):
            return "nan" if v != v else ("inf" if v == float("inf") else ("-inf" if v == float("-inf") else repr(v)))
        if isinstance(v, list):
            return "[" + ", ".join(literal(x) for x in v) + "]"
        if isinstance(v, str):
            return json.dumps(v)
        return str(v)

    *tables, key = path.split(".")
    head = f"[{'.'.join(tables)}]\n" if tables else ""
    return head + f"{key} = {literal(value)}\n"


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(KEYS), toml_values)
def test_fuzzed_specs_raise_only_spec_errors(key, value):
    text = ("" if key == "class" else 'class = "cup"\n') + to_toml(key, value)
    try:
        parse_spec(text)
    except SpmError as exc:
        assert "\n" not in str(exc)


_SHARD = {}


def shard_bytes(folder):
    """A small valid shard's bytes (made once; not a fixture, so failures do not print it)."""
    if "bytes" not in _SHARD:
        from tests.helpers import make_arrays

        path = folder / "valid.h5"
        write_shard(path, make_arrays(n=3, h=16, w=16), {"seed": 0, "renderer": "x"})
        _SHARD["bytes"] = path.read_bytes()
    return _SHARD["bytes"]


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_fuzzed_shard_bytes_raise_only_shard_errors(tmp_path, data):
    raw = bytearray(shard_bytes(tmp_path))
    for _ in range(data.draw(st.integers(1, 8))):
        i = data.draw(st.integers(0, len(raw) - 1))
        raw[i] = data.draw(st.integers(0, 255))
    if data.draw(st.booleans()):
        raw = raw[: data.draw(st.integers(0, len(raw)))]
    path = tmp_path / f"f{data.draw(st.integers(0, 10**9))}.h5"
    path.write_bytes(bytes(raw))
    from spm_data.pipelines.validate import validate_shard

    try:
        read_shard(path)
    except SpmError:
        pass
    problems = validate_shard(path)  # never raises: problems are listed
    assert isinstance(problems, list)
