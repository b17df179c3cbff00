"""N3M selection on hand-made point sets whose right markers are known."""

import numpy as np

from spm_model.methods.n3m_select import choose, flatness, grow, select_markers


def test_flatness_is_one_for_a_tetrahedron_and_zero_for_a_plane():
    tetra = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=float)
    assert abs(flatness(tetra) - 1.0) < 1e-9
    square = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], dtype=float)
    assert flatness(square) < 1e-12
    assert flatness(tetra[:3]) == 0.0


def table():
    """Ten good points on the plane z = 0 near the origin, two off it (z = 0.02) and one
    far away; all detected in views 0-3, the far one in view 4 only."""
    flat = [[x, y, 0.0] for x in (0.0, 0.01, 0.02) for y in (0.0, 0.01, 0.02)] + [[0.03, 0.0, 0.0]]
    positions = np.array(flat + [[0.01, 0.01, 0.02], [0.0, 0.02, 0.02], [0.5, 0.5, 0.5]])
    quality = np.r_[np.full(10, 0.9), 0.5, 0.4, 1.0]
    detected = np.zeros((13, 5), dtype=bool)
    detected[:12, :4] = True
    detected[12, 4] = True
    return positions, quality, detected


def test_grow_keeps_markers_local_spread_and_not_coplanar():
    positions, quality, detected = table()
    marker = grow(0, positions, quality, detected, size=5, radius=0.05, min_gap=0.005, min_relief=0.2)
    assert marker is not None and len(set(marker.tolist())) == 5
    assert 12 not in marker                                           # too far, never co-detected
    assert flatness(positions[marker]) >= 0.2                         # so an off-plane point is in it
    assert set(marker.tolist()) & {10, 11}
    gaps = np.linalg.norm(positions[marker][:, None] - positions[marker][None], axis=2)
    assert gaps[~np.eye(5, dtype=bool)].min() >= 0.005
    assert np.linalg.norm(positions[marker] - positions[0], axis=1).max() <= 0.05
    # Only the plane within reach: no marker can be non-coplanar.
    assert grow(0, positions[:10], quality[:10], detected[:10], size=5, radius=0.05, min_gap=0.005,
                min_relief=0.2) is None


def test_choose_covers_views_and_never_lets_markers_share_two_points():
    quality = np.ones(12)
    detected = np.zeros((12, 3), dtype=bool)
    detected[0:4, 0] = True                                           # marker A seen in view 0
    detected[4:8, 1] = True                                           # marker B in view 1
    detected[8:12, 2] = True
    markers = np.array([[0, 1, 2, 3], [0, 1, 2, 4], [4, 5, 6, 7], [8, 9, 10, 11], [8, 9, 10, 11]])
    chosen = choose(markers, quality, detected, per_view=1, max_markers=10)
    assert sorted(chosen.tolist())[:2] == [0, 2] and len(chosen) == 3   # one per view; no duplicates
    assert len(choose(markers, quality, detected, per_view=1, max_markers=2)) == 2


def test_select_markers_on_the_table():
    positions, quality, detected = table()
    found = select_markers(positions, quality, detected, size=5, radius=0.05, min_gap=0.005, min_relief=0.2,
                           per_view=2, max_markers=10)
    assert len(found) >= 1
    for marker in found:
        assert flatness(positions[marker]) >= 0.2
    shared = [len(set(a) & set(b)) for i, a in enumerate(found.tolist()) for b in found.tolist()[i + 1:]]
    assert all(s <= 1 for s in shared)


def cloud(seed: int, n: int = 300):
    """A random object: points in a 10 cm cube, qualities on a coarse scale (many ties, some zero),
    each point detected in a random subset of 12 views."""
    rng = np.random.default_rng(seed)
    positions = rng.uniform(0, 0.1, (n, 3))
    positions[: n // 4, 2] = 0.05                                     # a plane: flat sets must be refused
    quality = rng.integers(0, 5, n) / 4.0
    detected = rng.random((n, 12)) < 0.6
    return positions, quality, detected


def test_candidates_are_the_markers_grow_finds_seed_by_seed():
    from spm_model.methods.n3m_select import candidates

    for seed, (size, relief) in enumerate([(5, 0.1), (4, 0.3), (6, 0.05)]):
        positions, quality, detected = cloud(seed)
        kwargs = dict(size=size, radius=0.03, min_gap=0.004, min_relief=relief)
        found = candidates(positions, quality, detected, **kwargs)
        grown = [grow(int(s), positions, quality, detected, **kwargs) for s in np.flatnonzero(quality > 0)]
        expected = np.array([m for m in grown if m is not None]).reshape(-1, size)
        assert len(expected) > 20 and len(expected) < (quality > 0).sum()   # some seeds fail: both paths tried
        assert found.dtype == np.int64 and np.array_equal(found, expected)
    assert candidates(positions, np.zeros(len(positions)), detected, **kwargs).shape == (0, size)
