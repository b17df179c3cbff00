import numpy as np
import pytest

from spm_data.core.poses import wrap_degrees
from spm_model.base.estimator import ModelError
from spm_model.spm.regressor import RBFPoseRegressor
from tests.helpers import N, labels, vectors


def smooth_labels(X):
    """A known smooth map from 2-D inputs to labels whose angles cross +-180."""
    az = np.degrees(np.arctan2(X[:, 1], X[:, 0]))          # all the way round
    return np.column_stack([90 + 20 * X[:, 0], 5 * X[:, 1], wrap_degrees(-(az + 90)),
                            0.1 * X[:, 0], -0.05 * X[:, 1], 0.7 + 0.1 * X[:, 0] * X[:, 1]])


def circle(n, seed):
    t = np.random.default_rng(seed).uniform(0, 2 * np.pi, n)
    r = np.random.default_rng(seed + 1).uniform(0.8, 1.2, n)
    return np.column_stack([r * np.cos(t), r * np.sin(t)])


def angular_error(a, b):
    return np.abs(wrap_degrees(a - b))


def test_recovers_a_known_smooth_function_across_the_wrap():
    X, Xt = circle(400, 0), circle(100, 7)
    model = RBFPoseRegressor(alpha=1e-4).fit(X, smooth_labels(X))
    pred, true = model.predict(Xt), smooth_labels(Xt)
    assert np.median(angular_error(pred[:, :3], true[:, :3])) < 0.5   # degrees
    assert np.abs(pred[:, 3:] - true[:, 3:]).max() < 0.01               # metres
    near_wrap = np.abs(true[:, 2]) > 170
    assert near_wrap.any() and angular_error(pred[near_wrap, 2], true[near_wrap, 2]).max() < 3


def test_training_with_noise_smooths_and_stays_accurate():
    X, Xt = circle(200, 1), circle(50, 9)
    model = RBFPoseRegressor(noise=0.02, noise_copies=3, seed=0).fit(X, smooth_labels(X))
    assert model.X_fit_.shape == (800, 2)
    assert np.median(angular_error(model.predict(Xt)[:, 2], smooth_labels(Xt)[:, 2])) < 3


def test_estimator_contract_and_messages():
    m = RBFPoseRegressor(kernel_coef=2.0, alpha=0.5)
    assert (m.kernel_coef, m.alpha, m.noise) == (2.0, 0.5, 0.0) and not hasattr(m, "dual_coef_")
    with pytest.raises(ModelError, match=r"^this RBFPoseRegressor is not fitted yet; call fit\(X, y\) first$"):
        m.predict(np.zeros((1, 2)))
    with pytest.raises(ValueError, match=r"y \(n, 6\)"):
        m.fit(np.zeros((3, 2)), np.zeros((3, 5)))
    X = circle(20, 2)
    assert m.fit(X, smooth_labels(X)) is m
    with pytest.raises(ValueError, match="expected X with 2 columns"):
        m.predict(np.zeros((1, 3)))
    with pytest.raises(TypeError):
        RBFPoseRegressor(1.0)  # keyword-only


def test_width_scale_divides_the_median_heuristic_kernel_coef():
    X = circle(60, 3)
    y = smooth_labels(X)
    base = RBFPoseRegressor().fit(X, y)
    d2 = ((X[:, None] - X[None]) ** 2).sum(axis=2)
    assert base.kernel_coef_ == 1.0 / np.median(d2[d2 > 0])                 # the default: today's heuristic
    wide = RBFPoseRegressor(width_scale=10.0).fit(X, y)
    assert wide.kernel_coef_ == pytest.approx(base.kernel_coef_ / 10.0, rel=1e-12)
    # an explicit coefficient wins
    assert RBFPoseRegressor(kernel_coef=2.0, width_scale=10.0).fit(X, y).kernel_coef_ == 2.0
    with pytest.raises(ValueError, match="width_scale"):
        RBFPoseRegressor(width_scale=0.0).fit(X, y)


def test_regressor_from_state_predicts_as_the_fitted_one():
    X, y = vectors(N, 0, 4), labels(N, 0)
    model = RBFPoseRegressor(alpha=0.01, noise=0.01, noise_copies=1).fit(X, y)
    state = {k: getattr(model, k) for k in RBFPoseRegressor.FITTED}
    rebuilt = RBFPoseRegressor.from_state(**state, alpha=0.01, noise=0.01, noise_copies=1)
    assert rebuilt.alpha == 0.01 and rebuilt.X_fit_ is model.X_fit_
    assert np.array_equal(rebuilt.predict(vectors(5, 1, 4)), model.predict(vectors(5, 1, 4)))
    with pytest.raises(ModelError, match=r"not fitted yet \(mean_ not set\)"):
        RBFPoseRegressor.from_state(**{k: v for k, v in state.items() if k != "mean_"})
    with pytest.raises(ModelError, match="from_state: unknown beta_"):
        RBFPoseRegressor.from_state(**state, beta_=1)
