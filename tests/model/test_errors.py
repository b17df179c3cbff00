"""spm_model.errors: the model's error types, each an SpmError (so the CLI prints ``error:``)."""

import pytest

from spm_data.errors import SpmError
from spm_model.errors import BunchError, EllipseError, FeatureError, ModelError, SparseError


@pytest.mark.parametrize("cls", [ModelError, FeatureError, SparseError, BunchError, EllipseError])
def test_every_model_error_is_an_spm_error(cls):
    with pytest.raises(SpmError, match="^bad thing$"):
        raise cls("bad thing")
    assert not issubclass(cls, (ValueError, OSError))   # not caught by accident as a library's error


def test_the_specific_errors_are_caught_as_their_family():
    assert issubclass(SparseError, ModelError) and not issubclass(SparseError, FeatureError)
    assert issubclass(BunchError, FeatureError) and issubclass(EllipseError, FeatureError)
    assert not issubclass(FeatureError, ModelError)
