"""spm_model.bench.extract: path neighbours stay within an instance."""

import numpy as np

from spm_model.bench.extract import path_neighbours


def test_path_neighbours_stay_within_an_instance():
    inst = np.array([0, 0, 0, 1, 1])
    path = np.array([0, 1, 2, 0, 2])
    assert path_neighbours(inst, path) == [[1], [0, 2], [1], [], []]
