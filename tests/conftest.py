"""Fixtures shared by every test folder (helpers to import are in tests/helpers.py)."""

import os
import sys

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
# One BLAS thread per process (set before numpy loads; worker processes inherit it). The suite's
# matrices are small and many tests run two worker processes: OpenBLAS's threads spin on the
# 2 cores and cost 2-3x the CPU (e.g. SPMEstimator's batched simplex) for no gain.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
# No progress lines unless a test asks for them (monkeypatch.setenv("SPM_PROGRESS_EVERY", ...)): off a
# terminal a command prints one every 10 s, so on a busy machine a slow step added a line to the output
# of tests that expect an exact one (issue 47). Set here, so commands run in-process and the
# subprocesses tests start (they inherit os.environ) alike; whatever the shell had set is overridden.
os.environ["SPM_PROGRESS_EVERY"] = "86400"

import pytest  # noqa: E402

from tests.helpers import (OBJECTS, PLUGIN, coil_image, png_bytes, write_pyrender_128_spec,  # noqa: E402
                           write_small_specs)


@pytest.fixture(autouse=True)
def _signal_handlers_as_found():
    """Every test starts with the process's SIGINT and SIGTERM handlers and the interrupt state
    (spm_data.jobs.outcome) as the worker had them, whatever an earlier test on the same pytest
    worker did (a command run in-process, ray.init, a test that set its own handler)."""
    import signal

    from spm_data.jobs import outcome

    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    state = (outcome._received[0], outcome._pending[0])
    yield
    for signum, handler in handlers.items():
        if handler is not None and signal.getsignal(signum) is not handler:
            signal.signal(signum, handler)
    outcome._received[0], outcome._pending[0] = state


@pytest.fixture(autouse=True)
def _every_import_passes_validate(monkeypatch):
    """Importers write only what validate accepts (issue 47 item 3): every import any test makes in
    this process (each importer's own tests, the CLI's, the hostile inputs') is validated as it
    completes, with spm_data.pipelines.validate.validate_folder, the library call behind
    ``spm-data validate``; a problem fails the test that imported."""
    from spm_data.pipelines.validate import validate_folder
    from spm_data.formats import importing

    run = importing.run_shard_jobs

    def run_and_validate(fn, jobs, out_dir, **kwargs):
        summary = run(fn, jobs, out_dir, **kwargs)
        if not (summary.interrupted or summary.failed) and summary.frames:
            problems = validate_folder(out_dir)
            assert problems == [], f"validate refuses what the importer wrote to {out_dir}: {problems}"
        return summary

    monkeypatch.setattr(importing, "run_shard_jobs", run_and_validate)


@pytest.fixture
def small_specs_dir(tmp_path):
    """A specs folder with two tiny classes (18 views x 2 instances each)."""
    return write_small_specs(tmp_path / "specs")


@pytest.fixture(scope="session")
def model_shards(tmp_path_factory):
    """Three classes (box, car, cup), 48 views each at 128x128 (pyrender): enough
    keypoints for the SPM pipeline. Read-only for tests: copy before writing."""
    from spm_data.pipelines.render_jobs import load_run_specs, render_dataset

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
    from spm_data.pipelines.render_jobs import load_run_specs, render_dataset

    root = tmp_path_factory.mktemp("instances")
    specs = root / "specs"
    specs.mkdir()
    for cls in ("car", "cup"):
        write_pyrender_128_spec(specs, cls, seed=2, az_stop=115, el=20, per_shard=96, instances=2)
    render_dataset(load_run_specs(all_classes=True, specs_dir=specs), root / "shards")
    return root / "shards"


@pytest.fixture(scope="session")
def plugin_module(tmp_path_factory):
    """The module my_pose (tests/helpers.py PLUGIN: MeanPose, WrongShape), importable for the session."""
    import importlib

    folder = tmp_path_factory.mktemp("plugin")
    (folder / "my_pose.py").write_text(PLUGIN)
    sys.path.insert(0, str(folder))
    try:
        yield importlib.import_module("my_pose")
    finally:
        sys.path.remove(str(folder))
        sys.modules.pop("my_pose", None)


@pytest.fixture(scope="session")
def loco_report(model_shards, plugin_module, tmp_path_factory):
    """The full benchmark, run once for the tests that check it (test_train, the plug-in test in
    test_protocols): train() on model_shards, loco protocol, 2 runs, every built-in method and
    the plug-in my_pose:MeanPose. Returns (train's result, the report folder). Read-only."""
    from spm_model.pipelines.train import train
    from spm_model.spm.features import FeatureConfig

    report = tmp_path_factory.mktemp("loco") / "report"
    before = os.environ.get("SPM_TEST_NOTES")
    os.environ["SPM_TEST_NOTES"] = str(report.parent / "notes.jsonl")   # what MeanPose saw
    try:
        result = train(model_shards, report, protocol="loco", runs=2, features=FeatureConfig(ellipse="direct"),
                       estimators=["my_pose:MeanPose"])
    finally:
        os.environ.pop("SPM_TEST_NOTES") if before is None else os.environ.update(SPM_TEST_NOTES=before)
    return result, report


@pytest.fixture
def notes(tmp_path, monkeypatch):
    """What a test's plug-ins note (tests/helpers.py ``note``; they run in processes of their own):
    a callable returning the JSON values noted so far, in order."""
    import json

    path = tmp_path / "notes.jsonl"
    monkeypatch.setenv("SPM_TEST_NOTES", str(path))
    return lambda: [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


@pytest.fixture(scope="module")
def coil_folder(tmp_path_factory):
    """A COIL-100 folder of objects OBJECTS (72 views each), one view missing, one PNG
    truncated and a foreign file. Read-only for tests."""
    root = tmp_path_factory.mktemp("coil") / "coil-100"
    root.mkdir()
    for obj in OBJECTS:
        for angle in range(0, 360, 5):
            (root / f"obj{obj}__{angle}.png").write_bytes(png_bytes(coil_image(obj, angle)))
    (root / "obj12__45.png").unlink()                              # a missing view
    good = (root / "obj12__40.png").read_bytes()
    (root / "obj12__40.png").write_bytes(good[: len(good) // 2])   # a truncated PNG
    (root / "README.txt").write_text("COIL-100\n")                 # a foreign file
    return root
