"""spm_data.io.files: files written whole or not at all, and their SHA-256."""

import hashlib
import json

import numpy as np
import pytest

from spm_data.io.files import atomic_file, file_sha256, partial_path, write_json_atomic, write_npz_atomic


def test_partial_path_is_hidden_beside_the_target(tmp_path):
    assert partial_path(tmp_path / "a.h5") == tmp_path / ".a.h5.partial"


def test_file_sha256_of_known_bytes(tmp_path):
    (tmp_path / "empty").write_bytes(b"")
    (tmp_path / "abc").write_bytes(b"abc")
    assert file_sha256(tmp_path / "empty") == "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855"
    assert file_sha256(tmp_path / "abc") == "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
    big = bytes(range(256)) * 10_000                     # several 1 MiB blocks
    (tmp_path / "big").write_bytes(big)
    assert file_sha256(tmp_path / "big") == hashlib.sha256(big).hexdigest()


def test_atomic_file_replaces_the_target_when_the_block_completes(tmp_path):
    target = tmp_path / "out.txt"
    target.write_text("old")
    with atomic_file(target) as tmp:
        assert tmp == tmp_path / ".out.txt.partial" and not tmp.exists()
        tmp.write_text("new")
        assert target.read_text() == "old"              # nothing changes until the block ends
    assert target.read_text() == "new" and sorted(p.name for p in tmp_path.iterdir()) == ["out.txt"]


def test_atomic_file_leaves_the_old_file_on_error(tmp_path):
    target = tmp_path / "out.txt"
    target.write_text("old")
    with pytest.raises(RuntimeError, match="half way"):
        with atomic_file(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("half way")
    assert target.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["out.txt"]
    with pytest.raises(RuntimeError):
        with atomic_file(tmp_path / "new.txt", tmp_path / "mine.tmp") as tmp:   # a chosen temporary name
            assert tmp == tmp_path / "mine.tmp"
            tmp.write_text("half")
            raise RuntimeError("stop")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.txt"]     # no target made, no temporary left


def test_write_npz_atomic(tmp_path):
    path = write_npz_atomic(tmp_path / "m.npz", a=np.arange(3), b=np.eye(2))
    assert path == tmp_path / "m.npz" and sorted(p.name for p in tmp_path.iterdir()) == ["m.npz"]
    with np.load(path) as z:
        assert sorted(z.files) == ["a", "b"]
        np.testing.assert_array_equal(z["a"], [0, 1, 2])
        np.testing.assert_array_equal(z["b"], np.eye(2))
    before = path.read_bytes()
    with pytest.raises(FileNotFoundError):   # the temporary file cannot be made: the old model stays
        write_npz_atomic(path, tmp_path / "no-such-folder" / ".m.npz.partial", a=np.zeros(1))
    assert path.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["m.npz"]


def test_write_json_atomic_is_sorted_indented_and_ends_in_a_newline(tmp_path):
    write_json_atomic(tmp_path / "m.json", {"b": 1, "a": [1, 2]})
    text = (tmp_path / "m.json").read_text()
    assert text == '{\n  "a": [\n    1,\n    2\n  ],\n  "b": 1\n}\n'
    assert json.loads(text) == {"a": [1, 2], "b": 1}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.json"]


def test_a_bounded_read_allocates_what_the_file_holds_not_the_limit(tmp_path):
    """Issue 47: read(limit + 1) with a 4 GiB limit was a MemoryError under `ulimit -v` below
    ~4 GiB (spm predict, spm evaluate on small VMs). In a child under a 1.5 GiB address-space limit."""
    import subprocess
    import sys

    (tmp_path / "small.bin").write_bytes(b"x" * 1000)
    code = ("import resource, sys; resource.setrlimit(resource.RLIMIT_AS, (1536 << 20, 1536 << 20)); "
            "from spm_data.io.files import read_regular_file; "
            "print(len(read_regular_file(sys.argv[1], 4 << 30)))")
    r = subprocess.run([sys.executable, "-c", code, str(tmp_path / "small.bin")], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0 and r.stdout == "1000\n", r.stderr


def test_a_bounded_read_reads_a_file_in_pieces_and_refuses_one_over_the_limit(tmp_path, monkeypatch):
    from spm_data.io import files

    data = bytes(range(256)) * 9000   # 2.2 MB: the first piece, then 1 MiB pieces if it grew
    (tmp_path / "f").write_bytes(data)
    assert files.read_regular_file(tmp_path / "f", len(data)) == data
    with pytest.raises(ValueError, match=f"{len(data):,} bytes is over the limit of 1,000 bytes"):
        files.read_regular_file(tmp_path / "f", 1000)
    with open(tmp_path / "f", "rb", buffering=0) as fh:   # a file that grew since it was measured
        assert files._read_at_most(fh, len(data) + 1, first=10, size=9) == data
