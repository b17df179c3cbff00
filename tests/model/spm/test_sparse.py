import numpy as np
import pytest

from spm_model.spm.sparse import SparseError, fit_projection, l1_weights, sparse_weights


def data(t=40, m=16, seed=0):
    rng = np.random.default_rng(seed)
    # Samples near a 3-D manifold inside 16 dimensions, normalised like the foci vectors.
    z = rng.normal(size=(t, 3))
    X = np.abs(z @ rng.normal(size=(3, m)) + 3.0) + 0.01 * rng.normal(size=(t, m))
    return X / np.linalg.norm(X, axis=1, keepdims=True)


def test_eq5_weights_reconstruct_each_sample_sum_to_one_and_skip_it():
    X = data()
    S = sparse_weights(X.T, "exact")
    np.testing.assert_allclose(X.T @ S, X.T, atol=1e-7)    # m_i = M r_i
    np.testing.assert_allclose(S.sum(axis=0), 1.0, atol=1e-9)  # 1^T r_i = 1
    np.testing.assert_array_equal(np.diag(S), 0.0)          # r_ii = 0
    assert np.mean(np.abs(S) > 1e-9) < 0.5                   # sparse


def test_l1_solution_is_minimal():
    rng = np.random.default_rng(1)
    D = rng.normal(size=(5, 12))
    r_true = np.zeros(12)
    r_true[[2, 7]] = [0.4, 0.6]
    r = l1_weights(D @ r_true, D)
    np.testing.assert_allclose(D @ r, D @ r_true, atol=1e-8)
    assert np.abs(r).sum() <= np.abs(r_true).sum() + 1e-9


def test_knn_solver_matches_the_exact_solve_when_it_sees_every_sample():
    X = data(t=30)
    exact = fit_projection(X, method="exact")
    knn = fit_projection(X, method="knn", k=29)
    np.testing.assert_allclose(knn.W, exact.W, atol=1e-6)
    np.testing.assert_allclose(knn.transform(X), exact.transform(X), atol=1e-6)


def test_knn_weights_still_reconstruct():
    X = data(t=60, seed=3)
    S = sparse_weights(X.T, "knn", k=24)
    np.testing.assert_allclose(X.T @ S, X.T, atol=1e-7)
    assert (np.count_nonzero(np.abs(S) > 1e-12, axis=0) <= 24).all()


def test_projection_keeps_the_sparse_structure_better_than_random_directions():
    X = data(t=40, seed=5)
    proj = fit_projection(X, dims=2)
    S = sparse_weights(X.T)
    M = X.T
    Sb = S + S.T - S.T @ S

    def ratio(w):
        return float(w @ M @ Sb @ M.T @ w / (w @ M @ M.T @ w))

    best = ratio(proj.W[:, 0])
    rng = np.random.default_rng(0)
    assert all(best >= ratio(rng.normal(size=16)) - 1e-9 for _ in range(200))


def test_too_few_samples():
    with pytest.raises(SparseError, match="at least 3 samples"):
        sparse_weights(np.ones((16, 2)))
