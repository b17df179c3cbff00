"""benchmarks/protocol_times.py --compare: a garbage, truncated or summary-less results.json,
or a folder that is not there, is one `error:` line and exit 1, never a traceback (issue 47)."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("content", ["\x00garbage\xff", '{"summary": {"meth', '{"schema": 1}', '{"summary": '
                                                                                               '{"methods": 3}}'])
def test_compare_of_a_garbage_results_json_is_one_error_line(tmp_path, content):
    for side in ("a", "b"):
        (tmp_path / side / "loco").mkdir(parents=True)
        (tmp_path / side / "loco" / "results.json").write_text(content, errors="surrogateescape")
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "protocol_times.py"), "--compare",
                        str(tmp_path / "a"), str(tmp_path / "b")], capture_output=True, text=True, timeout=300)
    assert r.returncode == 1 and r.stdout == "", r
    assert r.stderr.count("\n") == 1 and r.stderr.startswith(
        f"error: {tmp_path / 'a' / 'loco' / 'results.json'}: not a results.json spm train wrote ("), r.stderr


def test_compare_of_a_missing_folder_is_one_error_line(tmp_path):
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "protocol_times.py"), "--compare",
                        str(tmp_path / "none"), str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 1 and r.stderr == f"error: {tmp_path / 'none'}: no such folder; give two --out folders " \
                                             "of this script\n", r.stderr
