"""spm_model.base.feature_memo: features remembered by image content, within a byte budget, and in a
folder shared by processes (damaged files recomputed, half-written ones of dead processes removed)."""

import numpy as np
import pytest

import os
import socket

from spm_data.errors import SpmWarning
from spm_model.base import feature_memo
from spm_model.base.feature_memo import (clear_memo, content_key, load_entry, memo_stats, memoized, save_entry,
                                         use_folder)


@pytest.fixture(autouse=True)
def empty_memo(monkeypatch):
    monkeypatch.delenv("SPM_FEATURE_MEMO_MB", raising=False)
    monkeypatch.setattr(feature_memo, "_warned", [False])
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
    with pytest.warns(SpmWarning, match="feature memo entry .* is damaged, cut short, of an earlier format or of "
                                        "another image; recomputed and rewritten"):
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
    key = content_key(("k",), np.arange(3))
    save_entry(tmp_path / "e.feat", arrays, key)
    back = load_entry(tmp_path / "e.feat", key)
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


def _features(img):
    """A stand-in feature whose every value depends on the image: a wrong entry shows."""
    return img.astype(np.float64).sum(axis=(0, 1)), np.flatnonzero(img[..., 0].ravel() > 128)


def _fill(folder, images):
    use_folder(folder)
    clear_memo()
    return [memoized(("f", 1), (img,), lambda img=img: _features(img)) for img in images]


def _reread(folder, images, calls):
    """Every image's features from ``folder`` in a fresh process's memo, counting recomputations."""
    clear_memo()
    use_folder(folder)

    def compute(img):
        calls.append(1)
        return _features(img)
    return [memoized(("f", 1), (img,), lambda img=img: compute(img)) for img in images]


def _same(a, b):
    return all(all(np.array_equal(x, y) and x.dtype == y.dtype for x, y in zip(p, q)) for p, q in zip(a, b))


def test_rotated_swapped_flipped_and_cut_entries_are_recomputed_never_used(tmp_path):
    """The audit's case: entries renamed in a ring (mtime kept) were served for the wrong images.
    Now the key inside each entry is checked: every scenario equals a cache-less run exactly."""
    rng = np.random.default_rng(5)
    images = [rng.integers(0, 255, (12, 12, 3), dtype=np.uint8) for _ in range(50)]
    truth = [_features(img) for img in images]                      # a run without any cache
    folder = tmp_path / "memo"
    assert _same(_fill(folder, images), truth)
    files = sorted(folder.glob("*/*.feat"))
    assert len(files) == 50
    contents = [p.read_bytes() for p in files]
    stats = [p.stat() for p in files]
    for p, data, st in zip(files, contents[1:] + contents[:1], stats):  # rotate all 50, mtimes kept
        p.write_bytes(data)
        os.utime(p, ns=(st.st_atime_ns, st.st_mtime_ns))
    calls = []
    with pytest.warns(SpmWarning, match="feature memo entry"):
        assert _same(_reread(folder, images, calls), truth)
    assert len(calls) == 50                                         # every one recomputed ...
    calls.clear()
    assert _same(_reread(folder, images, calls), truth) and calls == []   # ... and rewritten: served again
    # Flip every byte of one entry, one at a time, and cut it at every length.
    target, key = files[0], bytes.fromhex(files[0].stem)
    good = target.read_bytes()
    for i in range(len(good)):
        bad = bytearray(good)
        bad[i] ^= 0x01
        target.write_bytes(bytes(bad))
        assert load_entry(target, key) is None, f"byte {i} flipped and still served"
    for n in range(len(good)):
        target.write_bytes(good[:n])
        assert load_entry(target, key) is None, f"cut at {n} and still served"
    target.write_bytes(good)
    assert load_entry(target, key) is not None and load_entry(target, bytes(20)) is None


def test_entries_of_the_earlier_formats_are_recomputed(tmp_path):
    img = np.random.default_rng(2).integers(0, 255, (16, 16, 3), dtype=np.uint8)
    folder = tmp_path / "memo"
    first = _fill(folder, [img])
    path = next(folder.glob("*/*.feat"))
    old = path.read_bytes()
    body = b"SPMFEAT1" + old[28:-20]                        # version 1: no key inside
    import hashlib

    path.write_bytes(body + hashlib.blake2b(body, digest_size=20).digest())
    np.savez(path.with_suffix(".npz"), *[a + 1 for a in first[0]])   # the older .npz beside it: never read
    calls = []
    with pytest.warns(SpmWarning):
        assert _same(_reread(folder, [img], calls), first) and len(calls) == 1


def test_an_entry_another_worker_writes_meanwhile_is_no_damage(tmp_path, monkeypatch, recwarn):
    """Two workers missing the same image at once: the second worker's entry appearing while this
    one looks is no damaged entry (it once said so, in a spurious warning on every first run)."""
    img = np.random.default_rng(2).integers(0, 255, (16, 16, 3), dtype=np.uint8)
    use_folder(tmp_path / "memo")
    real_load = feature_memo.load_entry

    def load_then_the_other_worker_writes(path, key):
        found = real_load(path, key)
        if found is None and not path.exists():
            path.parent.mkdir(parents=True, exist_ok=True)
            save_entry(path, counting([])(img), key)
        return found

    monkeypatch.setattr(feature_memo, "load_entry", load_then_the_other_worker_writes)
    calls = []
    memoized(("k",), (img,), lambda: counting(calls)(img))
    assert len(calls) == 1 and not [w for w in recwarn if issubclass(w.category, SpmWarning)]
