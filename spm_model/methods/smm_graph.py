"""SMM's manifold distance and its part selection as a graph problem (docs/method.md).

An image is the constellation of its parts: which parts are present and where
(spm_model/methods/smm_parts.py). The squared distance between two images,
restricted to a part set S, is a sum over the vertices and edges of the complete
graph on S:

    d_S(i, j)^2 = sum_{k in S} [ (p_ik - p_jk)^2 + p_ik p_jk |m_ik - m_jk|^2 ]
                + sum_{k<l in S} p_ik p_il p_jk p_jl |(m_il - m_ik) - (m_jl - m_jk)|^2

(p presence 0/1, m object-centred location). *Alignment* lowers the mean of d_S^2
over pairs of frames at the same pose on different sequences (the intra-class
distance given a pose); *expansion* raises its mean over pairs of frames of one
sequence in different pose classes (the inter-pose distance given an instance).
Because d_S^2 splits over vertices and edges, so does the objective
``mean_expand d_S^2 - alignment_weight * mean_align d_S^2``: it is the weight of
the subgraph induced by S in a graph whose vertex and edge weights are the
per-part and per-pair terms. Choosing the ``m`` parts of greatest total weight is
the (vertex- and edge-weighted) densest-m-subgraph problem, NP-hard; it is solved
exactly by enumeration when that is small and otherwise by greedy growth and
pairwise swaps to a local optimum.
"""

from __future__ import annotations

import itertools
from math import comb

import numpy as np

EXACT_LIMIT = 20000  # enumerate every m-subset when there are at most this many


def _edge_form(u, delta):
    """(n, P) weights ``u`` and (n, P, 2) displacements -> (P, P) sums over n of
    u_k u_l |delta_l - delta_k|^2 (zero diagonal)."""
    a = np.einsum("npd,npd->np", delta, delta)
    out = (u * a).T @ u
    out = out + out.T
    for d in range(delta.shape[2]):
        ud = u * delta[:, :, d]
        out -= 2.0 * ud.T @ ud
    np.fill_diagonal(out, 0.0)
    return out


def pair_terms(presence, location, pairs):
    """Sums over image pairs of the distance's vertex and edge terms.

    presence (n, P) bool/0-1, location (n, P, 2) object-centred, pairs (q, 2) int rows
    into them. Returns (P, P) float64: the diagonal holds each part's vertex term
    summed over the pairs, entry (k, l) the edge term of parts k and l."""
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    p = np.asarray(presence, dtype=np.float64)
    loc = np.asarray(location, dtype=np.float64)
    pi, pj = p[pairs[:, 0]], p[pairs[:, 1]]
    both = pi * pj
    delta = loc[pairs[:, 1]] - loc[pairs[:, 0]]
    vertex = ((pi - pj) ** 2).sum(axis=0) + (both * np.einsum("npd,npd->np", delta, delta)).sum(axis=0)
    out = _edge_form(both, delta)
    out[np.diag_indices_from(out)] = vertex
    return out


def selection_weights(presence, location, align_pairs, expand_pairs, alignment_weight: float = 1.0):
    """(P, P) symmetric weights of the selection graph: mean over ``expand_pairs`` of the
    distance terms minus ``alignment_weight`` times their mean over ``align_pairs``
    (vertex weights on the diagonal)."""
    expand = pair_terms(presence, location, expand_pairs) / max(len(expand_pairs), 1)
    align = pair_terms(presence, location, align_pairs) / max(len(align_pairs), 1)
    return expand - alignment_weight * align


def subgraph_value(W, subset) -> float:
    """Weight of the subgraph induced by ``subset``: its vertex weights plus the
    weights of its edges, each counted once."""
    s = np.asarray(subset, dtype=np.int64)
    block = np.asarray(W)[np.ix_(s, s)]
    return float(np.trace(block) + (block.sum() - np.trace(block)) / 2.0)


def exact_subgraph(W, m: int) -> np.ndarray:
    """The ``m``-vertex subset of greatest :func:`subgraph_value`, by enumeration
    (sorted indices; first found on ties)."""
    W = np.asarray(W, dtype=np.float64)
    best, best_value = None, -np.inf
    for subset in itertools.combinations(range(len(W)), m):
        value = subgraph_value(W, subset)
        if value > best_value + 1e-12:
            best, best_value = subset, value
    return np.array(best, dtype=np.int64)


def local_subgraph(W, m: int, max_swaps: int = 1000) -> np.ndarray:
    """An ``m``-vertex subset of high :func:`subgraph_value`: grown greedily (each step
    adds the vertex of greatest gain), then improved by the best single swap (one
    vertex out, one in) while a swap gains; a local optimum (sorted indices)."""
    W = np.asarray(W, dtype=np.float64)
    vertex = np.diag(W).copy()
    off = W - np.diag(vertex)
    inside = np.zeros(len(W), dtype=bool)
    links = np.zeros(len(W))          # sum of edge weights to the chosen vertices
    for _ in range(m):
        gain = np.where(inside, -np.inf, vertex + links)
        k = int(np.argmax(gain))
        inside[k] = True
        links += off[k]
    for _ in range(max_swaps):
        ins, outs = np.flatnonzero(inside), np.flatnonzero(~inside)
        if len(outs) == 0:
            break
        keep = vertex[ins] + links[ins]                                  # (a,) what a adds now
        come = vertex[outs][None, :] + links[outs][None, :] - off[np.ix_(ins, outs)]  # (a, b)
        change = come - keep[:, None]
        a, b = np.unravel_index(int(np.argmax(change)), change.shape)
        if change[a, b] <= 1e-12:
            break
        inside[ins[a]], inside[outs[b]] = False, True
        links += off[outs[b]] - off[ins[a]]
    return np.flatnonzero(inside)


def select_parts(W, m: int) -> np.ndarray:
    """The part subset of size ``m`` (sorted indices) maximising the alignment-expansion
    objective: exact when C(P, m) <= 20000, else :func:`local_subgraph`."""
    m = min(int(m), len(W))
    if comb(len(W), m) <= EXACT_LIMIT:
        return exact_subgraph(W, m)
    return local_subgraph(W, m)


def _cross(ua, xa, ub, xb):
    """sum_k ua_k ub_k |xa_k - xb_k|^2 for every row pair: (na, nb)."""
    a2 = np.einsum("ned,ned->ne", xa, xa)
    b2 = np.einsum("ned,ned->ne", xb, xb)
    out = (ua * a2) @ ub.T + ua @ (ub * b2).T
    for d in range(xa.shape[2]):
        out -= 2.0 * (ua * xa[:, :, d]) @ (ub * xb[:, :, d]).T
    return out


def manifold_distances(pa, la, pb, lb) -> np.ndarray:
    """Squared distances d_S^2 (module docstring) between images A and B described by
    their selected parts: presence (na, s) / (nb, s), location (na, s, 2) / (nb, s, 2).
    Returns (na, nb) float64, >= 0 up to rounding.

    The edge sum is not taken edge by edge (s(s-1)/2 of them): with w_k = p_ak p_bk and
    delta_k = m_ak - m_bk, the relative positions differ by delta_l - delta_k, so
    sum_{k<l} w_k w_l |delta_l - delta_k|^2 = W * S - |V|^2, where W = sum w_k,
    S = sum w_k |delta_k|^2 (the vertex terms' location part) and V = sum w_k delta_k:
    O(s) per pair of images instead of O(s^2)."""
    pa, pb = np.asarray(pa, np.float64), np.asarray(pb, np.float64)
    la, lb = np.asarray(la, np.float64), np.asarray(lb, np.float64)
    both = pa @ pb.T                                                          # W
    located = _cross(pa, la, pb, lb)                                          # S
    vertex = (pa ** 2).sum(1)[:, None] + (pb ** 2).sum(1)[None, :] - 2.0 * both + located
    spread = sum(((pa * la[:, :, d]) @ pb.T - pa @ (pb * lb[:, :, d]).T) ** 2  # |V|^2
                 for d in range(la.shape[2]))
    return np.maximum(vertex + both * located - spread, 0.0)


def _rotation_angles(qa, qb, within: float = 180.0) -> np.ndarray:
    """Unit quaternions (na, 4), (nb, 4) -> (na, nb) rotation angles between them, degrees;
    inf where the angle is clearly above ``within`` (the arccos is only taken near or
    below it: most pairs are far, and the arccos was most of the pairs' cost)."""
    dots = np.clip(np.abs(qa @ qb.T), 0.0, 1.0)
    # cos is decreasing on [0, pi/2]: dots below this bound give angles above ``within``
    # by far more than rounding, so skipping them changes no comparison with it.
    half = np.radians(within) / 2.0 + 1e-6
    near = dots >= np.cos(half) if half < np.pi / 2 else np.ones(dots.shape, dtype=bool)
    out = np.full(dots.shape, np.inf)
    out[near] = np.degrees(2.0 * np.arccos(dots[near]))
    return out


def _align_partner(i, candidates, presence, location):
    """Of ``candidates`` (frames of other sequences at frame i's pose), the one nearest
    to frame i under every part's manifold distance (the first without parts)."""
    if presence is None or len(candidates) == 1:
        return int(candidates[0])
    d = manifold_distances(presence[[i]], location[[i]], presence[candidates], location[candidates])[0]
    return int(candidates[np.argmin(d)])


def training_pairs(quaternions, sequences, bins, tolerance: float = 5.0, max_pairs: int = 4000, seed: int = 0,
                   presence=None, location=None):
    """The frame pairs the objective averages over.

    quaternions (n, 4) unit (the frames' rotations), sequences (n,) ids, bins (n,) pose
    classes. Alignment pairs: each of up to ``max_pairs`` frames (drawn at random) with
    a frame of another sequence whose rotation is within ``tolerance`` degrees: the
    nearest under the manifold distance over every part when ``presence`` (n, P) and
    ``location`` (n, P, 2) are given (the other instance most like it: the manifold it
    is to be aligned with), else the nearest in rotation. Expansion pairs: each of those
    frames with a random frame of its own sequence in another pose class. Returns two
    (q, 2) int64 arrays."""
    rng = np.random.default_rng(seed)
    q = np.asarray(quaternions, dtype=np.float64)
    sequences, bins = np.asarray(sequences), np.asarray(bins)
    if presence is not None:
        presence, location = np.asarray(presence, np.float64), np.asarray(location, np.float64)
    n = len(q)
    chosen = np.sort(rng.choice(n, size=min(n, max_pairs), replace=False))
    align, expand = [], []
    for start in range(0, len(chosen), 512):
        rows = chosen[start:start + 512]
        angles = _rotation_angles(q[rows], q, within=tolerance)
        angles[sequences[rows][:, None] == sequences[None, :]] = np.inf
        for r, i in enumerate(rows):
            candidates = np.flatnonzero(angles[r] <= tolerance)
            candidates = candidates[np.argsort(angles[r, candidates], kind="stable")]
            if len(candidates):
                align.append((i, _align_partner(i, candidates, presence, location)))
    for i in chosen:
        others = np.flatnonzero((sequences == sequences[i]) & (bins != bins[i]))
        if len(others):
            expand.append((i, int(rng.choice(others))))
    as_array = lambda pairs: np.array(pairs, dtype=np.int64).reshape(-1, 2)  # noqa: E731
    return as_array(align), as_array(expand)
