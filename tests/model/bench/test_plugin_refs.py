"""spm_model.bench.plugin_refs: a plug-in is described from a process of its own (its module is
never imported here), refused in one line when it cannot be, and resolved to its class only
where a method's process asks for it."""

import sys

import pytest

from spm_model.errors import ModelError
from spm_model.base.estimator import Needs
from spm_model.bench.plugin_refs import PluginRef, check_spec, describe, resolve

PLUGINS = '''
from spm_model.base.estimator import Needs


class Declares:
    NEEDS = Needs(frames=4, depth=True)
    DETERMINISTIC = True

    def fit(self, frames, poses):
        return self

    def predict(self, frames):
        return None


class Plain(Declares):
    NEEDS = Needs()
    DETERMINISTIC = False
'''


@pytest.fixture
def plugin_module(tmp_path, monkeypatch):
    name = f"refs_plugin_{tmp_path.name.replace('-', '_')}"
    (tmp_path / f"{name}.py").write_text(PLUGINS)
    (tmp_path / f"{name}_exits.py").write_text("raise SystemExit(3)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    return name


@pytest.mark.parametrize("spec", ["my_pose", "my_pose:", ":Cls", "my pose:Cls", "my_pose:Cls:x", ""])
def test_a_spec_not_of_the_form_module_class_is_refused_in_one_line(spec):
    with pytest.raises(ModelError, match="MODULE:CLASS") as err:
        check_spec(spec)
    assert "\n" not in str(err.value)
    assert check_spec("pkg.my_pose:MyEstimator") == "pkg.my_pose:MyEstimator"


def test_describe_reads_what_each_class_declares_without_importing_its_module_here(plugin_module):
    refs = describe([f"{plugin_module}:Declares", f"{plugin_module}:Plain", f"{plugin_module}:Declares"])
    assert list(refs) == [f"{plugin_module}:Declares", f"{plugin_module}:Plain"]   # each once
    declares, plain = refs.values()
    assert declares.NEEDS == Needs(frames=4, depth=True) and declares.DETERMINISTIC is True
    assert plain.NEEDS == Needs() and plain.DETERMINISTIC is False
    assert declares.__name__ == "Declares" and declares.unpicklable is None
    assert plugin_module not in sys.modules   # described in a child, never imported in this process


def test_a_module_that_exits_as_it_is_imported_is_one_line_naming_it(plugin_module):
    spec = f"{plugin_module}_exits:Cls"
    with pytest.raises(ModelError) as err:
        describe([spec])
    assert str(err.value).startswith(f"--estimator {spec}") and "SystemExit" in str(err.value)
    assert "\n" not in str(err.value)


def test_resolve_imports_the_class_of_a_ref_and_passes_a_class_through(plugin_module):
    cls = resolve(PluginRef(f"{plugin_module}:Declares"))
    assert cls.__name__ == "Declares" and cls.NEEDS == Needs(frames=4, depth=True)
    assert resolve(dict) is dict
    assert describe([]) == {}
