"""spm_model.base.feature_memo: features remembered by image content, within a byte budget."""

import numpy as np
import pytest

from spm_model.base.feature_memo import clear_memo, content_key, memo_stats, memoized


@pytest.fixture(autouse=True)
def empty_memo(monkeypatch):
    monkeypatch.delenv("SPM_FEATURE_MEMO_MB", raising=False)
    clear_memo()
    yield
    clear_memo()


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
