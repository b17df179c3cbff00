"""spm_model.pipelines.evaluate: a file that is not an spm model is refused in one line."""

import numpy as np
import pytest

from spm_model.errors import ModelError
from spm_model.pipelines.evaluate import load_model


def test_a_foreign_file_is_not_a_model(tmp_path):
    path = tmp_path / "weights.npz"
    np.savez(path, W=np.zeros(3))
    with pytest.raises(ModelError, match=r"weights.npz"):
        load_model(path)
