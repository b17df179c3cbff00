import numpy as np
import pytest

from spm_model.spm.sparse import SparseError, fit_projection, l1_simplex, l1_weights, sparse_weights


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


def test_batched_simplex_equals_the_linprog_reference_on_random_problems():
    """Shared dictionary with one excluded column per problem (the exact solver's form)
    and per-problem dictionaries (the knn form): the l1 norms equal HiGHS's to 1e-9; the
    weights equal them to 1e-8 wherever the optimum is unique. It is not when the target
    lies inside the others' convex hull: then every convex combination that reproduces it
    has norm exactly 1 (sum r = 1), and each solver returns one vertex of that set."""
    rng = np.random.default_rng(7)
    m, n, P = 6, 40, 40
    A = np.vstack([rng.normal(size=(m, n)), np.ones((1, n))])
    b = A[:, :P].T + 0.05 * np.vstack([rng.normal(size=(m, P)), np.zeros((1, P))]).T
    r, ok = l1_simplex(A, b, exclude=np.arange(P))
    assert ok.all() and (r[np.arange(P), np.arange(P)] == 0).all()
    refs = [np.insert(l1_weights(b[p, :m], np.delete(A[:m], p, axis=1)), p, 0.0) for p in range(P)]
    check_against_reference(A, b, r, np.array(refs), unique_at_least=10)
    per_problem = rng.normal(size=(P, m + 1, 12))
    per_problem[:, m] = 1.0
    b = np.einsum("pmn,pn->pm", per_problem, rng.normal(0.3, 1.0, size=(P, 12)))
    b /= b[:, m:]
    r, ok = l1_simplex(per_problem, b)
    assert ok.all()
    refs = np.array([l1_weights(b[p, :m], per_problem[p, :m]) for p in range(P)])
    check_against_reference(per_problem, b, r, refs, unique_at_least=10)


def check_against_reference(A, b, r, refs, unique_at_least):
    Ar = np.einsum("mn,pn->pm", A, r) if A.ndim == 2 else np.einsum("pmn,pn->pm", A, r)
    np.testing.assert_allclose(Ar, b, atol=1e-9)
    np.testing.assert_allclose(np.abs(r).sum(axis=1), np.abs(refs).sum(axis=1), atol=1e-9)
    unique = np.abs(refs).sum(axis=1) > 1 + 1e-6        # some weight is negative
    assert unique.sum() >= unique_at_least
    np.testing.assert_allclose(r[unique], refs[unique], atol=1e-8)
    assert (np.count_nonzero(r, axis=1) <= A.shape[-2]).all()   # a vertex: at most m + 1 weights


def test_batched_simplex_flags_what_it_cannot_solve_and_sparse_weights_falls_back():
    """A target outside the dictionary's span is infeasible: not ok, zero weights; the
    exact solver then uses the reference's least-squares fallback for that sample."""
    D = np.array([[1.0, 0.0, 1.0], [0.0, 1.0, 1.0], [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    r, ok = l1_simplex(D, np.array([[0.5, 0.5, 0.0, 1.0], [0.0, 0.0, 1.0, 1.0]]))
    assert ok.tolist() == [True, False]
    np.testing.assert_allclose(r[0], [0.5, 0.5, 0.0], atol=1e-12)
    assert (r[1] == 0).all()
    # sample 3 is off the others' plane
    M = np.array([[0.0, 1.0, 0.0, 1.0], [0.0, 0.0, 1.0, 1.0], [0.0, 0.0, 0.0, 1.0]])
    S = sparse_weights(M)
    np.testing.assert_allclose(S[:3, 3], l1_weights(M[:, 3], M[:, :3]), atol=1e-9)
    assert np.abs(S[:3, 3]).sum() > 0 and S[3, 3] == 0.0
