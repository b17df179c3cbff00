"""smallest_k against the full stable sort it stands for."""

import numpy as np
import pytest

from spm_model.base.ranking import smallest_k


@pytest.mark.parametrize("values", ["ties", "uniform", "nan", "specials"])
def test_smallest_k_is_the_stable_sorts_first_columns(values):
    rng = np.random.default_rng(len(values))
    for _ in range(300):
        n, m, k = int(rng.integers(1, 6)), int(rng.integers(1, 600)), int(rng.integers(0, 12))
        if values == "ties":
            d = rng.integers(0, 4, (n, m)).astype(np.float64)
        elif values == "uniform":
            d = rng.random((n, m))
        elif values == "nan":                       # some rows with fewer than k numbers
            d = rng.integers(0, 3, (n, m)).astype(np.float64)
            d[rng.random((n, m)) < rng.random()] = np.nan
        else:
            d = rng.choice([0.0, -0.0, np.inf, -np.inf, 1.0, np.nan], (n, m))
        got = smallest_k(d, k)
        assert got.dtype == np.int64
        np.testing.assert_array_equal(got, np.argsort(d, axis=1, kind="stable")[:, :k])


def test_smallest_k_of_nothing():
    assert smallest_k(np.zeros((3, 0)), 5).shape == (3, 0)
    assert smallest_k(np.zeros((0, 40)), 5).shape == smallest_k(np.zeros((0, 400)), 5).shape == (0, 5)
    np.testing.assert_array_equal(smallest_k(np.array([[3.0, 1.0, 2.0]]), 9), [[1, 2, 0]])
    with pytest.raises(ValueError, match="k must be 0 or more, got -1"):
        smallest_k(np.zeros((2, 100)), -1)


def test_smallest_k_of_integers_and_booleans():
    rng = np.random.default_rng(7)
    for dtype in (np.int8, np.int64, np.uint8, bool):
        d = rng.integers(0, 3, (4, 300)).astype(dtype)
        np.testing.assert_array_equal(smallest_k(d, 5), np.argsort(d, axis=1, kind="stable")[:, :5])
