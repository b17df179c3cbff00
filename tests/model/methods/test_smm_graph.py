"""spm_model.methods.smm_graph: the distance's terms by hand, the objective equal to the
distance it decomposes, the subgraph solvers against enumeration, the training pairs,
and a toy manifold whose right parts are known."""

import numpy as np
from scipy.spatial.transform import Rotation

from spm_data.core.poses import camera_poses
from spm_model.methods.smm_graph import (_rotation_angles, exact_subgraph, local_subgraph, manifold_distances,
                                         pair_terms,
                                         select_parts, selection_weights, subgraph_value, training_pairs)


def test_pair_terms_by_hand():
    # Two images, two parts. Image 0: both present at (0,0) and (1,0); image 1: part 0 at
    # (0,1), part 1 at (1,2). Vertex 0: presence 0 + |(0,1)|^2 = 1; vertex 1: |(0,2)|^2 = 4;
    # edge: relative positions (1,0) and (1,1): |(0,1)|^2 = 1.
    presence = np.ones((2, 2), dtype=bool)
    location = np.array([[[0, 0], [1, 0]], [[0, 1], [1, 2]]], dtype=float)
    terms = pair_terms(presence, location, [[0, 1]])
    np.testing.assert_allclose(terms, [[1.0, 1.0], [1.0, 4.0]])
    # Part 1 missing in image 1: its vertex term is the presence change only, no edge.
    presence[1, 1] = False
    np.testing.assert_allclose(pair_terms(presence, location, [[0, 1]]), [[1.0, 0.0], [0.0, 1.0]])


def test_the_objective_is_the_distance_it_decomposes():
    rng = np.random.default_rng(0)
    presence = rng.random((30, 7)) < 0.7
    location = rng.normal(size=(30, 7, 2))
    align, expand = rng.integers(0, 30, (40, 2)), rng.integers(0, 30, (25, 2))
    W = selection_weights(presence, location, align, expand, alignment_weight=0.7)
    subset = np.array([0, 2, 3, 6])
    p, m = presence[:, subset].astype(float), location[:, subset]
    d = manifold_distances(p, m, p, m)
    direct = d[expand[:, 0], expand[:, 1]].mean() - 0.7 * d[align[:, 0], align[:, 1]].mean()
    assert subgraph_value(W, subset) == np.float64(direct) or np.isclose(subgraph_value(W, subset), direct)
    assert np.allclose(np.diag(d), 0.0, atol=1e-9) and np.allclose(d, d.T)


def test_local_search_matches_enumeration():
    rng = np.random.default_rng(1)
    # A planted subgraph: vertices 2, 5, 7, 11 strongly linked, the rest noise.
    W = rng.normal(scale=0.3, size=(14, 14))
    W = (W + W.T) / 2
    for a in (2, 5, 7, 11):
        for b in (2, 5, 7, 11):
            W[a, b] += 2.0
    assert exact_subgraph(W, 4).tolist() == [2, 5, 7, 11]
    assert local_subgraph(W, 4).tolist() == [2, 5, 7, 11]
    # On random graphs the local optimum is within 10% of the exact one.
    for seed in range(5):
        W = np.random.default_rng(10 + seed).normal(size=(12, 12))
        W = (W + W.T) / 2
        best = subgraph_value(W, exact_subgraph(W, 5))
        assert subgraph_value(W, local_subgraph(W, 5)) >= best - 0.1 * abs(best)
    assert select_parts(W, 5).tolist() == exact_subgraph(W, 5).tolist()  # small: enumerated


def _views(azimuths):
    R, t = camera_poses(azimuths, 20.0, 0.0, 0.6)
    return Rotation.from_matrix(R).as_quat()


def test_training_pairs():
    az = np.arange(0, 360, 5.0)
    q = np.vstack([_views(az), _views(az + 1.0)])     # two sequences, 1 degree apart
    sequences = np.repeat([0, 1], len(az))
    bins = np.tile((az // 45).astype(int), 2)
    align, expand = training_pairs(q, sequences, bins, tolerance=2.0, max_pairs=1000)
    assert len(align) == 2 * len(az)
    assert np.all(align[:, 1] == (align[:, 0] + len(az)) % (2 * len(az)))   # same view, other sequence
    assert len(expand) == 2 * len(az)
    assert np.all(sequences[expand[:, 0]] == sequences[expand[:, 1]])
    assert np.all(bins[expand[:, 0]] != bins[expand[:, 1]])
    none, _ = training_pairs(q, sequences, bins, tolerance=0.5, max_pairs=1000)
    assert len(none) == 0


def toy_manifold(seed=0, sequences=4, noise=0.01):
    """Sequences of views every 5 degrees. Parts 0-5 move with the pose the same way on
    every sequence (up to small noise); parts 6-9 are distractors (random place, random
    presence); parts 10-11 are present and static (aligned, but no expansion)."""
    rng = np.random.default_rng(seed)
    az = np.arange(0, 360, 5.0)
    n = len(az) * sequences
    presence = np.ones((n, 12), dtype=bool)
    location = np.zeros((n, 12, 2))
    phase = np.radians(az)[:, None] + np.arange(6)[None, :]
    moving = 0.5 * np.stack([np.cos(phase), np.sin(phase)], axis=-1)
    for s in range(sequences):
        rows = slice(s * len(az), (s + 1) * len(az))
        location[rows, :6] = moving + rng.normal(scale=noise, size=moving.shape)
        location[rows, 6:10] = rng.uniform(-1, 1, size=(len(az), 4, 2))
        presence[rows, 6:10] = rng.random((len(az), 4)) < 0.6
        location[rows, 10:] = [[0.3, -0.2], [-0.4, 0.1]]
    q = np.vstack([_views(az)] * sequences)
    return presence, location, q, np.repeat(np.arange(sequences), len(az)), np.tile((az // 45).astype(int), sequences)


def test_selection_picks_the_consistent_parts_of_a_toy_manifold():
    presence, location, q, sequences, bins = toy_manifold()
    align, expand = training_pairs(q, sequences, bins, tolerance=1.0, max_pairs=2000, presence=presence,
                                   location=location)
    W = selection_weights(presence, location, align, expand)
    assert select_parts(W, 6).tolist() == [0, 1, 2, 3, 4, 5]
    assert local_subgraph(W, 6).tolist() == [0, 1, 2, 3, 4, 5]
    # Static parts neither expand nor misalign: weight exactly 0; moving ones gain.
    vertex = np.diag(W)
    assert np.all(vertex[10:] == 0.0) and vertex[:6].min() > 0.1
    # Under the selected parts, the same pose on another sequence is the nearest frame.
    sel = [0, 1, 2, 3, 4, 5]
    d = manifold_distances(presence[:72, sel], location[:72, sel], presence[72:144, sel], location[72:144, sel])
    assert np.all(d.argmin(axis=1) == np.arange(72))


def test_alignment_partner_is_the_most_similar_sequence():
    # Three sequences at the same 72 views; sequence 2 shows sequence 0's constellation,
    # sequence 1 another one: frames of 0 align with 2, not with 1 (nearer in rotation).
    az = np.arange(0, 360, 5.0)
    q = np.vstack([_views(az), _views(az + 0.5), _views(az + 1.0)])
    sequences = np.repeat([0, 1, 2], len(az))
    bins = np.tile((az // 45).astype(int), 3)
    rng = np.random.default_rng(2)
    mine, other = rng.normal(size=(len(az), 5, 2)), rng.normal(size=(len(az), 5, 2))
    location = np.concatenate([mine, other, mine])
    presence = np.ones((3 * len(az), 5), dtype=bool)
    align, _ = training_pairs(q, sequences, bins, tolerance=2.0, max_pairs=1000, presence=presence, location=location)
    from_0 = align[sequences[align[:, 0]] == 0]
    assert len(from_0) == len(az)
    assert np.all(from_0[:, 1] == from_0[:, 0] + 2 * len(az))
    rotation_only, _ = training_pairs(q, sequences, bins, tolerance=2.0, max_pairs=1000)
    assert np.all(sequences[rotation_only[sequences[rotation_only[:, 0]] == 0, 1]] == 1)


def _distance_by_definition(pa, la, pb, lb):
    """d_S^2 of the module docstring, vertex by vertex and edge by edge."""
    out = np.zeros((len(pa), len(pb)))
    s = pa.shape[1]
    for i in range(len(pa)):
        for j in range(len(pb)):
            total = 0.0
            for k in range(s):
                total += (pa[i, k] - pb[j, k]) ** 2 + pa[i, k] * pb[j, k] * np.sum((la[i, k] - lb[j, k]) ** 2)
                for m in range(k + 1, s):
                    w = pa[i, k] * pa[i, m] * pb[j, k] * pb[j, m]
                    total += w * np.sum(((la[i, m] - la[i, k]) - (lb[j, m] - lb[j, k])) ** 2)
            out[i, j] = total
    return out


def test_manifold_distances_equal_the_definition_edge_by_edge():
    rng = np.random.default_rng(3)
    for s in (1, 2, 9):
        pa, pb = (rng.random((6, s)) < 0.6).astype(float), (rng.random((5, s)) < 0.6).astype(float)
        la, lb = rng.normal(size=(6, s, 2)) * 3, rng.normal(size=(5, s, 2)) * 3
        expected = _distance_by_definition(pa, la, pb, lb)
        np.testing.assert_allclose(manifold_distances(pa, la, pb, lb), expected, rtol=1e-12, atol=1e-10)
    # Identical images are at distance 0 up to rounding (distances here are 10^1-10^3).
    np.testing.assert_allclose(np.diag(manifold_distances(pa, la, pa, la)), 0.0, atol=1e-9)


def test_rotation_angles_skip_only_pairs_far_outside_the_tolerance():
    rng = np.random.default_rng(0)
    base = Rotation.random(100, random_state=1)
    q = [Rotation.random(500, random_state=2).as_quat()]
    for degrees in (0.0, 4.9999, 5.0, 5.0001, 30.0, 179.9):    # near the tolerances tested
        step = rng.normal(size=(100, 3))
        step *= np.radians(degrees) / np.linalg.norm(step, axis=1, keepdims=True)
        q.append((base * Rotation.from_rotvec(step)).as_quat())
    q = np.vstack(q + [base.as_quat()])
    plain = np.degrees(2.0 * np.arccos(np.clip(np.abs(q[-100:] @ q.T), 0.0, 1.0)))
    for tolerance in (0.0, 5.0, 30.0, 180.0):
        angles = _rotation_angles(q[-100:], q, within=tolerance)
        np.testing.assert_array_equal(angles <= tolerance, plain <= tolerance)
        np.testing.assert_array_equal(angles[angles <= tolerance], plain[plain <= tolerance])
        assert np.all(np.isinf(angles[plain > tolerance + 1e-3]) | (tolerance >= 179.9))
    np.testing.assert_array_equal(_rotation_angles(q[-100:], q), plain)
