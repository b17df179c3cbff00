import numpy as np
import pytest

from spm_model.methods.cnn_retrieval import BLOCK, cached_hogs, nearest_frames, uses_hog
from spm_model.methods.descriptors import HOG_SIZE
from spm_model.methods.template import hog_projection, project_hog
from tests.helpers import CachedFrames


def _unit(x):
    return (x / np.linalg.norm(x, axis=1, keepdims=True)).astype(np.float32)


@pytest.fixture
def arrays():
    rng = np.random.default_rng(3)
    n, m = 300, BLOCK + 90                                  # past one block of queries
    return (_unit(rng.normal(size=(m, 8))), _unit(rng.normal(size=(n, 8))),
            (0.3 * rng.normal(size=(m, 5))).astype(np.float32), (0.3 * rng.normal(size=(n, 5))).astype(np.float32))


def _scores(z, e, c, h, weight):
    """The module docstring's score, written out in float64 query by query."""
    z, e, c, h = (np.asarray(a, np.float64) for a in (z, e, c, h))
    return np.array([z[i] @ e.T + weight * (1 - 0.5 * ((h - c[i]) ** 2).sum(axis=1)) for i in range(len(z))])


@pytest.mark.parametrize("weight", [0.5, 2.0, 8.0])
def test_every_frame_scored_picks_the_best_score(arrays, weight):
    z, e, c, h = arrays
    picked = nearest_frames(z, e, c, h, weight, -1)
    scores = _scores(z, e, c, h, weight)
    best = scores.max(axis=1)
    assert np.allclose(scores[np.arange(len(z)), picked], best, atol=1e-5)
    assert (picked == np.argmax(scores, axis=1)).mean() > 0.99            # float32 rounding may swap near-ties
    assert (picked != np.argmax(z @ e.T, axis=1)).any()                  # HOG did act


def test_a_shortlist_scores_only_the_nearest_embeddings(arrays):
    z, e, c, h = arrays
    picked = nearest_frames(z, e, c, h, 2.0, 16)
    similarity = z @ e.T
    sixteenth = np.sort(similarity, axis=1)[:, -16]
    assert (similarity[np.arange(len(z)), picked] >= sixteenth).all()
    scores = np.where(similarity >= sixteenth[:, None], _scores(z, e, c, h, 2.0), -np.inf)
    assert np.allclose(scores[np.arange(len(z)), picked], scores.max(axis=1), atol=1e-5)


def test_no_shortlist_is_the_nearest_embedding_without_hog(arrays):
    z, e, c, h = arrays
    assert not uses_hog(0) and not uses_hog(1) and uses_hog(2) and uses_hog(-1)
    for shortlist in (0, 1):
        assert np.array_equal(nearest_frames(z, e, None, h[:, :0], 2.0, shortlist), np.argmax(z @ e.T, axis=1))


def test_blocks_of_queries_pick_as_one_query_at_a_time(arrays):
    z, e, c, h = arrays
    for shortlist in (-1, 16):
        together = nearest_frames(z, e, c, h, 4.0, shortlist)
        alone = [nearest_frames(z[i: i + 1], e, c[i: i + 1], h, 4.0, shortlist)[0] for i in range(0, len(z), 11)]
        assert np.array_equal(together[::11], alone)


def test_project_hog_in_float32_is_its_float64_map_rounded():
    rng = np.random.default_rng(3)
    hogs = rng.random((300, HOG_SIZE)).astype(np.float32)
    mean, axes = hog_projection(hogs[::3], 16)
    codes = project_hog(hogs, mean, axes, np.float32)
    assert codes.dtype == np.float32 and codes.shape == (300, 16)
    assert np.allclose(codes, project_hog(hogs, mean, axes), atol=1e-5)
    assert np.isfinite(project_hog(np.zeros((2, HOG_SIZE)), mean, axes, np.float32)).all()   # an all-zero descriptor


def test_cached_hogs_read_the_template_column_and_nothing_without_it():
    template = np.arange(4 * (HOG_SIZE + 7), dtype=np.float64).reshape(4, HOG_SIZE + 7)
    hogs = cached_hogs(CachedFrames({"template": template}, [{}] * 4))
    assert hogs.dtype == np.float32 and np.array_equal(hogs, template[:, :HOG_SIZE].astype(np.float32))
    assert cached_hogs(CachedFrames({}, [{}] * 4)) is None
    assert cached_hogs([{}] * 4) is None
