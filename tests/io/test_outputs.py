"""spm_data.io.outputs: where an output may go, checked before any work, and the folders a failed
write made removed again."""

import errno
import os

import pytest

from spm_data.io.outputs import nearest_existing, removing_created, space_fix, top_created, unwritable


def test_nearest_existing_walks_up_to_what_exists(tmp_path):
    assert nearest_existing(tmp_path) == tmp_path
    assert nearest_existing(tmp_path / "a" / "b" / "c.png") == tmp_path
    (tmp_path / "a").mkdir()
    assert nearest_existing(tmp_path / "a" / "b" / "c.png") == tmp_path / "a"
    (tmp_path / "link").symlink_to(tmp_path / "gone")      # a dangling link exists as a name
    assert nearest_existing(tmp_path / "link" / "x") == tmp_path / "link"


def test_unwritable_names_the_file_or_read_only_folder_in_the_way(tmp_path):
    assert unwritable(tmp_path / "new" / "deeper") is None
    (tmp_path / "notes").write_text("mine")
    assert unwritable(tmp_path / "notes") == (tmp_path / "notes", "file")
    assert unwritable(tmp_path / "notes" / "sub" / "x.png") == (tmp_path / "notes", "file")


def test_unwritable_read_only(tmp_path, monkeypatch):
    locked = tmp_path / "locked"
    locked.mkdir()
    real_access = os.access
    # Root ignores permissions: say what os.access says for a read-only folder to anyone else.
    monkeypatch.setattr(os, "access", lambda p, mode: False if os.fspath(p) == str(locked) else real_access(p, mode))
    assert unwritable(locked / "out") == (locked, "read-only")
    assert unwritable(tmp_path / "elsewhere") is None


def test_top_created_is_the_outermost_folder_making_the_parents_would_create(tmp_path):
    assert top_created(tmp_path / "x.png") is None
    assert top_created(tmp_path / "a" / "b" / "x.png") == tmp_path / "a"
    (tmp_path / "a").mkdir()
    assert top_created(tmp_path / "a" / "b" / "x.png") == tmp_path / "a" / "b"


def test_removing_created_removes_only_what_a_failed_write_made(tmp_path):
    (tmp_path / "keep").mkdir()
    target = tmp_path / "keep" / "new" / "deeper" / "x.png"
    with pytest.raises(OSError):
        with removing_created(target):
            target.parent.mkdir(parents=True)
            target.write_text("half")
            raise OSError(errno.ENOSPC, "No space left on device")
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["keep"]
    with removing_created(target):                         # success: everything stays
        target.parent.mkdir(parents=True)
        target.write_text("whole")
    assert target.read_text() == "whole"


def test_space_fix():
    assert space_fix(OSError(errno.ENOSPC, "full"), "other") == "free space there"
    assert space_fix(OSError(errno.EDQUOT, "quota"), "other") == "free space there"
    assert space_fix(OSError(errno.EACCES, "denied"), "give --out a writable folder") == "give --out a writable folder"
