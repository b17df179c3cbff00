"""spm_model's public face: each name resolves to the library's own object, on first use."""

import importlib
import subprocess
import sys

import pytest

import spm_model


@pytest.mark.parametrize("name", sorted(spm_model.PUBLIC))
def test_every_public_name_is_the_library_object(name):
    assert getattr(spm_model, name) is getattr(importlib.import_module(spm_model.PUBLIC[name]), name)
    assert name in spm_model.__all__


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'evaluate'"):
        spm_model.evaluate


def test_importing_the_package_imports_nothing_of_the_model():
    code = "import sys, spm_model; print(sorted(m for m in sys.modules if m.startswith('spm_model.')))"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == "[]", r.stderr
