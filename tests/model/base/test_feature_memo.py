"""spm_model.base.feature_memo: features remembered by image content, within a byte budget, and in a
folder shared by processes (damaged files recomputed, half-written ones of dead processes removed)."""

import numpy as np
import pytest

import os
import socket

from spm_model.base.feature_memo import (clear_memo, content_key, load_entry, memo_stats, memoized, save_entry,
                                         use_folder)


@pytest.fixture(autouse=True)
def empty_memo(monkeypatch):
    monkeypatch.delenv("SPM_FEATURE_MEMO_MB", raising=False)
    clear_memo()
    use_folder(None)
    yield
    clear_memo()
    use_folder(None)


def counting(calls):
    def compute(img):
        calls.append(1)
        return img.sum(axis=2).astype(np.float64), np.arange(3)
    return compute


def test_the_same_pixels_are_computed_once_and_served_read_only():
    calls = []
    f = counting(calls)
    img = np.random.default_rng(0).integers(0, 255, (8, 8, 3), dtype=np.uint8)
    first = memoized(("k", 1), (img,), lambda: f(img))
    again = memoized(("k", 1), (img.copy(),), lambda: f(img))         # equal content, another array
    assert len(calls) == 1 and again is first and np.array_equal(first[0], img.sum(axis=2))
    with pytest.raises(ValueError):
        again[0][0, 0] = 1                                              # shared: callers must copy
    other = img.copy()
    other[3, 3, 0] ^= 1
    memoized(("k", 1), (other,), lambda: f(other))                      # one bit differs
    memoized(("k", 2), (img,), lambda: f(img))                          # other parameters
    assert len(calls) == 3 and memo_stats()["hits"] == 1 and memo_stats()["entries"] == 3


def test_keys_tell_dtype_and_shape_apart():
    a = np.zeros((4, 4), np.uint8)
    assert content_key(("k",), a) != content_key(("k",), a.astype(bool))
    assert content_key(("k",), a) != content_key(("k",), a.reshape(2, 8))
    assert content_key(("k",), a) == content_key(("k",), a.copy())


def test_a_full_memo_keeps_what_it_has_and_zero_turns_it_off(monkeypatch):
    calls = []
    f = counting(calls)
    imgs = [np.full((32, 32, 3), v, np.uint8) for v in range(4)]
    monkeypatch.setenv("SPM_FEATURE_MEMO_MB", str(2.5 * (32 * 32 * 8 + 3 * 8 + 200) / 2 ** 20))  # room for two
    for img in imgs + imgs:
        memoized(("k",), (img,), lambda: f(img))
    assert memo_stats()["entries"] == 2 and len(calls) == 6             # the first two served twice
    monkeypatch.setenv("SPM_FEATURE_MEMO_MB", "0")
    clear_memo()
    for img in imgs[:1] * 3:
        memoized(("k",), (img,), lambda: f(img))
    assert memo_stats()["entries"] == 0 and len(calls) == 9


def to_earlier_format(folder, change=lambda a: a):
    """Every .feat entry under ``folder`` rewritten as the earlier code's .npz (arrays passed
    through ``change``), the .feat removed."""
    for new in folder.glob("*/*.feat"):
        np.savez(new.with_suffix(".npz"), *[change(np.asarray(a)) for a in load_entry(new)])
        new.unlink()


def test_the_folder_serves_other_processes_and_damage_is_recomputed(tmp_path):
    calls = []
    f = counting(calls)
    img = np.random.default_rng(1).integers(0, 255, (16, 16, 3), dtype=np.uint8)
    use_folder(tmp_path / "memo")
    first = memoized(("k",), (img,), lambda: f(img))
    files = list((tmp_path / "memo").glob("*/*.feat"))
    assert len(files) == 1 and len(calls) == 1
    clear_memo()                                                        # as a new process would start
    served = memoized(("k",), (img,), lambda: f(img))
    assert len(calls) == 1 and memo_stats()["disk_hits"] == 1
    assert all(np.array_equal(a, b) and a.dtype == b.dtype for a, b in zip(first, served))
    data = bytearray(files[0].read_bytes())
    data[len(data) // 2] ^= 0xFF                                        # a flipped byte: the digest fails
    files[0].write_bytes(bytes(data))
    clear_memo()
    again = memoized(("k",), (img,), lambda: f(img))
    assert len(calls) == 2 and all(np.array_equal(a, b) for a, b in zip(first, again))
    clear_memo()
    memoized(("k",), (img,), lambda: f(img))                            # rewritten whole: served again
    assert len(calls) == 2 and memo_stats()["disk_hits"] == 1


def test_half_written_files_of_dead_processes_are_removed(tmp_path):
    folder = tmp_path / "memo" / "ab"
    folder.mkdir(parents=True)
    host = socket.gethostname()
    dead = folder / f".abcd.{host}.999999999.partial"
    live = folder / f".abce.{host}.{os.getpid()}.partial"
    other = folder / ".abcf.another-host.999999999.partial"
    for p in (dead, live, other):
        p.write_bytes(b"half")
    use_folder(tmp_path / "memo")
    assert not dead.exists() and live.exists() and other.exists()


def test_an_unwritable_folder_warns_once_and_memory_still_serves(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    calls = []
    f = counting(calls)
    img = np.zeros((4, 4, 3), np.uint8)
    use_folder(blocker / "memo")
    with pytest.warns(UserWarning, match="cannot write the feature memo"):
        memoized(("k",), (img,), lambda: f(img))
    memoized(("k",), (img,), lambda: f(img))
    assert len(calls) == 1 and memo_stats()["hits"] == 1


@pytest.mark.parametrize("arrays", [
    (np.zeros((0, 2)), np.zeros((0, 128), np.uint8)),                 # an image without keypoints
    (np.arange(6.0).reshape(3, 2), np.ones((3, 128), np.uint8), np.float32(2.5) * np.ones((), np.float32)),
    (np.arange(12.0).reshape(3, 4).T, np.arange(5, dtype=">i4")),     # not C-ordered; big-endian
    (),
])
def test_entries_read_back_exactly_and_in_place(tmp_path, arrays):
    save_entry(tmp_path / "e.feat", arrays)
    back = load_entry(tmp_path / "e.feat")
    assert len(back) == len(arrays)
    for a, b in zip(arrays, back):
        assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b)
        assert not b.flags.writeable and (b.size == 0 or b.ctypes.data % 16 == 0)


def test_entries_cut_short_or_of_another_format_are_refused(tmp_path):
    path = tmp_path / "e.feat"
    save_entry(path, (np.arange(10.0),))
    data = path.read_bytes()
    for broken in (data[:0], data[:7], data[:-1], data[:-21], b"PK" + data[2:]):
        path.write_bytes(broken)
        assert load_entry(path) is None
    assert load_entry(tmp_path / "missing.feat") is None
    with pytest.raises(ValueError, match="Python objects"):
        save_entry(path, (np.array([None]),))
    with pytest.raises(ValueError, match="named fields"):
        save_entry(path, (np.zeros(3, dtype=[("a", "<f8"), ("b", "<i4")]),))


def test_an_earlier_entry_in_a_folder_that_cannot_be_written_is_still_served(tmp_path, monkeypatch):
    from spm_model.base import feature_memo

    calls = []
    f = counting(calls)
    imgs = [np.full((8, 8, 3), v, np.uint8) for v in (1, 2)]
    use_folder(tmp_path / "memo")
    for img in imgs:
        memoized(("k",), (img,), lambda img=img: f(img))
    to_earlier_format(tmp_path / "memo")
    clear_memo()
    monkeypatch.setattr(feature_memo, "save_entry", lambda *a: (_ for _ in ()).throw(PermissionError("read-only")))
    for img in imgs:
        memoized(("k",), (img,), lambda img=img: f(img))
    assert len(calls) == 2 and memo_stats()["disk_hits"] == 2            # both served, none recomputed
    assert len(list((tmp_path / "memo").glob("*/*.npz"))) == 2          # and kept


def test_entries_of_the_earlier_format_are_served_and_rewritten(tmp_path):
    calls = []
    f = counting(calls)
    img = np.random.default_rng(2).integers(0, 255, (16, 16, 3), dtype=np.uint8)
    use_folder(tmp_path / "memo")
    first = memoized(("k",), (img,), lambda: f(img))
    new = next((tmp_path / "memo").glob("*/*.feat"))
    to_earlier_format(tmp_path / "memo", change=lambda a: a + 1)   # + 1: served, not recomputed
    clear_memo()
    served = memoized(("k",), (img,), lambda: f(img))
    assert len(calls) == 1 and all(np.array_equal(a + 1, b) for a, b in zip(first, served))
    assert new.exists() and not new.with_suffix(".npz").exists()
