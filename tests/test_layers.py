"""The pure-numpy core imports no Blender and no OpenGL (docs/architecture.md)."""

import subprocess
import sys

CORE = ["spm_data", "spm_data.poses", "spm_data.paths", "spm_data.meshes", "spm_data.textures", "spm_data.specs",
        "spm_data.shards", "spm_data.backgrounds", "spm_data.sheet", "spm_data.info", "spm_data.render",
        "spm_data.render_jobs", "spm_data.executor", "spm_data.occlusion", "spm_data.importing",
        "spm_data.validate", "spm_data.ray_executor", "spm_model.ellipse", "spm_model.manifold",
        "spm_model.keypoints", "spm_model.bunches", "spm_model.sparse",
        "spm_model.regressor", "spm_model.features", "spm_model.dataset", "spm_model.estimator",
        "spm_model.baselines", "spm_model.metrics", "spm_model.evaluation", "spm_model.report",
        "spm_model.train", "cli"]
FORBIDDEN = ("bpy", "OpenGL", "pyrender", "pyglet")


def test_core_imports_no_renderer_libraries():
    code = ("import sys\n" + "".join(f"import {m}\n" for m in CORE) +
            f"bad = sorted(m for m in sys.modules if m.split('.')[0] in {FORBIDDEN!r})\n"
            "print(','.join(bad))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == ""


def test_renderer_module_does_import_its_library():
    # The check above can fail: importing a backend really pulls its library in.
    code = ("import sys, spm_data.render.pyrender_backend as b; b._import_pyrender(); "
            "print('OpenGL' in sys.modules)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.stdout.strip() == "True", r.stderr
