"""spm_model.bench.isolated_child: the child's replies are JSON headers and plain arrays (never a
pickle), one per method or plug-in, and a plug-in whose module raises is one line, not the end
of the child."""

import io
import json
from multiprocessing import Pipe

import numpy as np
import pytest

from spm_model.bench.isolated_child import describe_one, send, serve_describe

PLUGIN = '''
class Good:
    DETERMINISTIC = True

    def fit(self, frames, poses):
        return self

    def predict(self, frames):
        return None
'''


def _replies(up_read) -> list:
    """Every (header, arrays) waiting on the read end of a pipe."""
    out = []
    while up_read.poll(0):
        header = json.loads(up_read.recv_bytes())
        arrays = [np.load(io.BytesIO(up_read.recv_bytes()), allow_pickle=False) for _ in range(header["arrays"])]
        out.append((header, arrays))
    return out


@pytest.fixture
def module(tmp_path, monkeypatch):
    name = f"child_plugin_{tmp_path.name.replace('-', '_')}"
    (tmp_path / f"{name}.py").write_text(PLUGIN)
    (tmp_path / f"{name}_raises.py").write_text("raise KeyboardInterrupt\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    return name


def test_send_writes_a_header_then_each_array_as_npy():
    read, write = Pipe(duplex=False)
    send(write, {"name": "m", "why": None}, [np.arange(6.0).reshape(1, 6), np.array([True])])
    [(header, arrays)] = _replies(read)
    assert header == {"name": "m", "why": None, "arrays": 2}
    np.testing.assert_array_equal(arrays[0], np.arange(6.0).reshape(1, 6))
    assert arrays[1].tolist() == [True]


def test_describe_one_reports_needs_determinism_and_picklability(module):
    info = describe_one(f"{module}:Good")
    assert info["needs"] == {"frames": 1, "depth": False, "spm_features": 0, "sequences": 1}
    assert info["deterministic"] is True and info["needs_error"] is None and info["unpicklable"] is None


def test_serve_describe_answers_each_spec_and_a_raising_module_is_one_line(module):
    down_read, down_write = Pipe(duplex=False)
    up_read, up_write = Pipe(duplex=False)
    specs = [f"{module}_raises:Cls", f"{module}:Good"]
    down_write.send(specs)
    serve_describe(down_read, up_write)   # KeyboardInterrupt from the plug-in's module stays in it
    (bad, _), (good, _) = _replies(up_read)
    assert bad["name"] == specs[0] and "KeyboardInterrupt" in bad["error"] and "\n" not in bad["error"]
    assert good["name"] == specs[1] and good["deterministic"] is True and "error" not in good


def test_a_spare_closed_before_any_work_ends_quietly(capfd):
    """EstimatorProcess.close sends None; a spare that got it as its first message printed a
    TypeError traceback (seen when the environment changed between splits) and exited 1."""
    from spm_model.bench.isolation import READY, EstimatorProcess

    child = EstimatorProcess()
    assert child.up.recv_bytes() == READY     # started: Python and our modules loaded
    child.send(None)
    assert child.proc.wait() == 0
    assert "Traceback" not in capfd.readouterr().err
