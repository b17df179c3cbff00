import contextlib
import os
import time

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import pytest


def wait_for(predicate, what, *, timeout=120.0, interval=0.05, proc=None):
    """Poll ``predicate()`` until it is truthy and return its value: tests wait for a
    state (a shard on disk, a lock taken), never a fixed time, so a loaded machine only
    makes them slower. AssertionError naming ``what`` after ``timeout`` seconds, or as
    soon as ``proc`` (a Popen) exits without the state reached (with its output)."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if proc is not None and proc.poll() is not None:
            value = predicate()  # reached just before it exited
            if value:
                return value
            output = proc.communicate()[0] if proc.stdout is not None else ""
            raise AssertionError(f"the process exited with status {proc.returncode} before {what}:\n{output}")
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")
        time.sleep(interval)


@contextlib.contextmanager
def reaped(proc, kill=None):
    """Yield ``proc`` (a Popen); on the way out a run still alive (a test that failed
    midway) is killed (``kill()``, default ``proc.kill``) and waited for, so no test
    leaves a process behind."""
    try:
        yield proc
    finally:
        if proc.poll() is None:
            (kill or proc.kill)()
            proc.communicate()


SMALL_SPEC = """
class = "{cls}"
seed = {seed}
[mesh]
instances = 2
[camera]
azimuth = [0, 25, 5]
elevation = [0, 10, 5]
distances = [0.6, 0.7]
[image]
width = 64
height = 64
[render]
renderer = "pyrender"
frames_per_shard = 8
"""


@pytest.fixture
def small_specs_dir(tmp_path):
    """A specs folder with two tiny classes (18 views x 2 instances each)."""
    folder = tmp_path / "specs"
    folder.mkdir()
    for cls in ("cup", "box"):
        (folder / f"{cls}.toml").write_text(SMALL_SPEC.format(cls=cls, seed=3))
    return folder


# One instance at 128x128 over azimuth 0..AZ_STOP x two elevations (EL, EL + 5):
# enough keypoints for the SPM pipeline (model tests) and quick to render (executor tests).
PYRENDER_128_SPEC = """
class = "{cls}"
seed = {seed}
[mesh]
instances = {instances}
[camera]
azimuth = [0, {az_stop}, 5]
elevation = [{el}, {el_stop}, 5]
distances = [0.6]
[image]
width = 128
height = 128
[render]
renderer = "pyrender"
frames_per_shard = {per_shard}
"""


def write_pyrender_128_spec(folder, cls, *, seed, az_stop, el, per_shard, instances=1):
    (folder / f"{cls}.toml").write_text(PYRENDER_128_SPEC.format(cls=cls, seed=seed, az_stop=az_stop, el=el,
                                                                 el_stop=el + 5, per_shard=per_shard,
                                                                 instances=instances))


@pytest.fixture(scope="session")
def model_shards(tmp_path_factory):
    """Three classes (box, car, cup), 48 views each at 128x128 (pyrender): enough
    keypoints for the SPM pipeline. Read-only for tests: copy before writing."""
    from spm_data.commands.render_jobs import load_run_specs, render_dataset

    root = tmp_path_factory.mktemp("model")
    specs = root / "specs"
    specs.mkdir()
    for cls in ("box", "car", "cup"):
        write_pyrender_128_spec(specs, cls, seed=1, az_stop=115, el=20, per_shard=48)
    render_dataset(load_run_specs(all_classes=True, specs_dir=specs), root / "shards")
    return root / "shards"


@pytest.fixture(scope="session")
def instance_shards(tmp_path_factory):
    """Two classes (car, cup), 2 instances each, 48 views per instance (azimuth 0-115
    at elevations 20 and 25) at 128x128 (pyrender). Read-only for tests."""
    from spm_data.commands.render_jobs import load_run_specs, render_dataset

    root = tmp_path_factory.mktemp("instances")
    specs = root / "specs"
    specs.mkdir()
    for cls in ("car", "cup"):
        write_pyrender_128_spec(specs, cls, seed=2, az_stop=115, el=20, per_shard=96, instances=2)
    render_dataset(load_run_specs(all_classes=True, specs_dir=specs), root / "shards")
    return root / "shards"
