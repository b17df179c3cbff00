import os

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import pytest

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
