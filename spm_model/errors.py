"""spm_model's error types: subclasses of the toolkit's one base error (spm_data.errors.SpmError),
so the CLI prints each as ``error: <message>`` and exits 1, like every other error."""

from spm_data.errors import SpmError


class ModelError(SpmError):
    """A model cannot be trained, loaded or applied to this input."""


class FeatureError(SpmError):
    """No feature for this image (too few keypoints, or no ellipse fits)."""


class SparseError(ModelError):
    """An l1 problem of the sparse re-projection had no solution (too few or degenerate samples)."""


class BunchError(FeatureError):
    """Too few keypoints to cluster into bunches."""


class EllipseError(FeatureError):
    """No ellipse fits the bunch centres (too few, coincident or collinear)."""
