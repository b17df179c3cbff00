"""Fixtures shared by every test folder (helpers to import are in tests/helpers.py)."""

import os

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
# One BLAS thread per process (set before numpy loads; worker processes inherit it). The suite's
# matrices are small and many tests run two worker processes: OpenBLAS's threads spin on the
# 2 cores and cost 2-3x the CPU (e.g. SPMEstimator's batched simplex) for no gain.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import pytest  # noqa: E402

from tests.helpers import OBJECTS, SMALL_SPEC, coil_image, png_bytes, write_pyrender_128_spec  # noqa: E402


@pytest.fixture
def small_specs_dir(tmp_path):
    """A specs folder with two tiny classes (18 views x 2 instances each)."""
    folder = tmp_path / "specs"
    folder.mkdir()
    for cls in ("cup", "box"):
        (folder / f"{cls}.toml").write_text(SMALL_SPEC.format(cls=cls, seed=3))
    return folder


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
