"""spm_data's public face: each name resolves to the library's own object, on first use."""

import subprocess
import sys

import pytest

import spm_data


@pytest.mark.parametrize("name", sorted(spm_data.PUBLIC))
def test_every_public_name_is_the_library_object(name):
    import importlib

    assert getattr(spm_data, name) is getattr(importlib.import_module(spm_data.PUBLIC[name]), name)
    assert name in spm_data.__all__


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'render_all'"):
        spm_data.render_all


def test_importing_the_package_imports_no_pipeline():
    code = "import sys, spm_data; print(sorted(m for m in sys.modules if m.startswith('spm_data.')))"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == "['spm_data.errors', 'spm_data.version']", r.stderr
