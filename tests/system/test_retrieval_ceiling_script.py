"""benchmarks/retrieval_ceiling.py: the best ±5° a method returning one of the test object's own
training views can reach, frame by frame."""

from types import SimpleNamespace

import numpy as np

from tests.helpers import load_script


def _script():
    return load_script("benchmarks/retrieval_ceiling.py", "retrieval_ceiling")


def _turntables(objects: int = 2):
    """Two objects on a turntable, 72 views 5 degrees apart (only the turntable angle measured)."""
    angle = np.tile(np.arange(0, 360, 5.0), objects)
    pose = np.zeros((len(angle), 6))
    pose[:, 2], pose[:, 5] = angle, 1.0
    measured = np.zeros((len(angle), 6), bool)
    measured[:, 2] = True
    return SimpleNamespace(class_name=np.array(["coil"] * len(angle)), instance_id=np.repeat(np.arange(objects), 72),
                           pose=pose, label_measured=measured)


def test_a_view_whose_neighbours_are_held_out_has_no_own_view_within_5_degrees():
    table = _turntables()
    test = np.array([10, 20, 72 + 40])            # object 0 at 50 and 100 degrees; object 1 at 200
    train = np.setdiff1d(np.arange(len(table.pose)), [9, 10, 11, 19, 20, 72 + 39, 72 + 40])
    errors = _script().nearest_own_view_errors(table, train, test)
    # 50: both neighbours (45, 55) out -> 40 or 60, 10; 100: 95 out, 105 in -> 5; object 1's 200: 195 out,
    # 205 in -> 5 (object 0's 195 and 200, in training, do not count for object 1)
    assert np.allclose(errors, [10.0, 5.0, 5.0])


def test_an_object_without_training_views_fails():
    table = _turntables()
    errors = _script().nearest_own_view_errors(table, np.arange(72), np.array([72, 100]))
    assert np.isinf(errors).all()
