"""The cnn method's retrieval: which training frame a query's pose is taken from.

Each query has a unit embedding (the network's, (m, embed) float32) and, unless HOG is off, a HOG
code (the reference's HOG of its 64 x 64 masked grey crop projected on the training frames' top
principal axes, (m, c) float32; template.py ``project_hog``). A training frame j scores

    cos(z, embeddings[j]) + weight x cos(HOG, codes[j])

where cos(HOG) is 1 - |a - b|^2 / 2 of the codes (the unit descriptors' cosine within the axes' span).
``shortlist`` says over which training frames: -1, every one (the default of CNNPose ``rerank``);
k >= 2, the k nearest embeddings only (the re-ranking this replaced); 0 or 1, none: the nearest
embedding alone, and no HOG is needed. Queries are scored BLOCK at a time, so memory stays at
BLOCK x n floats whatever the number of queries.
"""

from __future__ import annotations

import numpy as np

from spm_model.base.frames import cached_column
from spm_model.methods.descriptors import HOG_SIZE, hog_descriptor

BLOCK = 512   # queries scored at a time: 512 x 20,000 floats, not 4,000 x 20,000


SHORTLISTS = "-1 (every training frame), 0 or 1 (the nearest embedding) or a shortlist of k >= 2"


def valid_shortlist(shortlist) -> bool:
    """Whether ``shortlist`` (CNNPose ``rerank``) is one of SHORTLISTS: an integer >= -1."""
    try:
        return float(shortlist) == int(shortlist) and int(shortlist) >= -1
    except (TypeError, ValueError, OverflowError):
        return False


def uses_hog(shortlist: int) -> bool:
    """Whether retrieval with this ``shortlist`` (CNNPose ``rerank``) compares HOG codes."""
    return int(shortlist) < 0 or int(shortlist) >= 2


def crop_hogs(crops: np.ndarray) -> np.ndarray:
    """(n, 2, CROP, CROP) crops -> (n, HOG_SIZE) float32: the reference's HOG of each masked grey crop."""
    hog = hog_descriptor()
    out = np.zeros((len(crops), HOG_SIZE), np.float32)
    for i, c in enumerate(crops):
        out[i] = hog.compute(np.ascontiguousarray(c[0])).ravel()
    return out


def cached_hogs(frames) -> np.ndarray | None:
    """(n, HOG_SIZE) float32 HOG of a frame sequence's frames read from the feature cache's ``template``
    column (spm_model/base/frames.py), None when the sequence has no such column (a plain list of frame
    dicts). The column holds exactly crop_hogs' descriptor (descriptors.template_descriptor: the same
    crop of the same masked grey image, the same HOG), so a benchmark split reads it instead of computing
    it again (about 1.4 s a split at 20,000 training frames); NaN rows where a frame's mask is empty."""
    cached = cached_column(frames, "template")
    return None if cached is None else np.asarray(cached[:, :HOG_SIZE], np.float32)


def nearest_frames(z: np.ndarray, embeddings: np.ndarray, codes: np.ndarray | None, hog_codes: np.ndarray,
                   weight: float, shortlist: int) -> np.ndarray:
    """(m, e) query embeddings, (n, e) training embeddings, (m, c) query codes (None when not
    ``uses_hog``), (n, c) training codes -> (m,) int64 index of the best-scoring training frame
    (module docstring); with every frame scored, ties go to the lowest index (within a shortlist, to
    whichever argpartition lists first)."""
    if not uses_hog(shortlist):
        return np.argmax(z @ embeddings.T, axis=1)
    k = len(embeddings) if shortlist < 0 else min(int(shortlist), len(embeddings))
    squared = (hog_codes ** 2).sum(axis=1)
    out = np.zeros(len(z), np.int64)
    for s in range(0, len(z), BLOCK):
        similarity, c = z[s: s + BLOCK] @ embeddings.T, codes[s: s + BLOCK]
        if k == len(embeddings):
            hog_cos = 1 - 0.5 * ((c ** 2).sum(axis=1)[:, None] + squared[None] - 2 * c @ hog_codes.T)
            out[s: s + BLOCK] = np.argmax(similarity + weight * hog_cos, axis=1)
            continue
        short = np.argpartition(-similarity, k - 1, axis=1)[:, :k]
        hog_cos = 1 - 0.5 * ((hog_codes[short] - c[:, None, :]) ** 2).sum(axis=2)
        score = np.take_along_axis(similarity, short, axis=1) + weight * hog_cos
        out[s: s + BLOCK] = np.take_along_axis(short, np.argmax(score, axis=1)[:, None], axis=1)[:, 0]
    return out
