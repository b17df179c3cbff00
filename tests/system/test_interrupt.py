"""Ctrl-C or SIGTERM during `spm-data render`: finished shards kept, nothing partial, a resume hint, then a clean resume."""

import signal
import subprocess
import sys

import pytest

from tests.helpers import reaped, wait_for
from spm_data.io.shards import list_shards, read_manifest

pytestmark = pytest.mark.slow  # renders interrupted in subprocesses

# 2 instances x 240 views (azimuth every 15 degrees, elevation 0-45 every 5) at 32 x 32: 30 shards of 16 frames,
# small enough that the resume is quick, many enough that a signal sent after the first shard lands mid-run.
SPEC = ('class = "cup"\n[mesh]\ninstances = 2\n[camera]\nazimuth = [0, 345, 15]\nelevation = [0, 45, 5]\n'
        '[image]\nwidth = 32\nheight = 32\n[render]\nrenderer = "pyrender"\nframes_per_shard = 16\n')


@pytest.mark.parametrize("workers, sig", [(1, signal.SIGINT), (2, signal.SIGINT), (2, signal.SIGTERM)])
def test_sigint_keeps_complete_shards_and_resume_finishes(tmp_path, workers, sig):
    """SIGTERM (what `kill` and service managers send) is handled as Ctrl-C is."""
    spec = tmp_path / "cup.toml"
    spec.write_text(SPEC)
    out = tmp_path / "out"
    cmd = [sys.executable, "-c", "import cli; cli.data_cli()", "render", "--spec", str(spec), "--out", str(out),
           "--workers", str(workers)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    with reaped(proc):
        # Interrupt once the first shard is complete: at least 1 is kept, and the other 29
        # are far more work than the moment the signal takes to arrive, so 0 < n < 30.
        wait_for(lambda: out.is_dir() and list_shards(out), "the first complete shard", proc=proc, interval=0.01)
        proc.send_signal(sig)
        output, _ = proc.communicate(timeout=120)
    assert proc.returncode == 130, output
    assert "Traceback" not in output
    assert "run the same command again to resume" in output
    files = [p.name for p in list_shards(out)]
    assert 0 < len(files) < 30
    assert f"interrupted: {len(files)} of 30 shards are complete" in output
    assert [e["file"] for e in read_manifest(out)["shards"]] == files
    assert not list(out.glob(".*.partial")) and not (out / ".spm.lock").exists()
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert f"{len(files)} already complete" in done.stdout
    assert read_manifest(out)["frames"] == 480
