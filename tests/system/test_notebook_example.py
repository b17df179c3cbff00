"""docs/architecture.md's five-line notebook example, run as written: the public faces of
spm_data and spm_model are enough to render, read and benchmark."""

import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def example() -> str:
    text = (ROOT / "docs/architecture.md").read_text()
    section = text.split("## From a notebook", 1)[1]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_the_example_is_five_lines_of_the_public_faces_only():
    code = example()
    assert len([line for line in code.splitlines() if line.strip()]) == 5
    used = set(re.findall(r"\b(spm_data|spm_model)\.(\w+)", code))
    assert all("." not in name for _, name in used) and "pipelines" not in code and "import spm_data, spm_model" in code


def test_the_example_runs_and_reports_both_methods(tmp_path):
    (tmp_path / "render_specs").symlink_to(ROOT / "render_specs")
    env = {**os.environ, "PYOPENGL_PLATFORM": "egl", "SPM_PROGRESS_EVERY": "100000", "PYTHONPATH": str(ROOT)}
    r = subprocess.run([sys.executable, "-c", example()], cwd=tmp_path, env=env, capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.startswith("48 ") and "KNN K=1" in r.stdout and "chance" in r.stdout
    assert sorted(p.name for p in (tmp_path / "nb/render").glob("*.h5")) == ["box-00000.h5", "cup-00000.h5"]
    assert (tmp_path / "nb/report/results.json").is_file()
