import numpy as np
import pytest

from spm_data.errors import SpecError
from spm_data.core.paths import AngleRange, CameraGrid, camera_path


def test_default_path_has_936_views_in_single_5_degree_steps():
    path = camera_path(CameraGrid())
    assert len(path) == 936
    assert set(np.unique(path.elevation)) == set(np.arange(0, 61, 5.0))
    assert len(np.unique(path.azimuth)) == 72
    step_az = np.abs(np.diff(path.azimuth))
    step_el = np.abs(np.diff(path.elevation))
    # Exactly one of azimuth / elevation moves, by exactly 5 degrees.
    assert np.all((step_az == 5) ^ (step_el == 5))
    assert np.all((step_az == 0) | (step_az == 5)) and np.all((step_el == 0) | (step_el == 5))
    # Every (azimuth, elevation) pair appears once.
    assert len({(a, e) for a, e in zip(path.azimuth, path.elevation)}) == 936
    assert set(path.distance) == {0.6, 0.7, 0.8}


def test_grid_mode_multiplies_views_by_distances():
    grid = CameraGrid(azimuth=AngleRange(0, 10, 5), elevation=AngleRange(0, 5, 5), distances=(1.0, 2.0),
                      distance_mode="grid")
    path = camera_path(grid)
    assert len(path) == 12
    assert sorted(set(path.distance)) == [1.0, 2.0]
    assert np.all(path.distance[:6] == 1.0)


def test_roll_axis_walks_too():
    grid = CameraGrid(azimuth=AngleRange(0, 10, 5), elevation=AngleRange(0, 0, 5), roll=AngleRange(-5, 5, 5))
    path = camera_path(grid)
    assert len(path) == 9
    moves = (np.diff(path.azimuth) != 0).astype(int) + (np.diff(path.roll) != 0)
    assert np.all(moves == 1)


@pytest.mark.parametrize("grid, message", [
    (CameraGrid(azimuth=AngleRange(0, 355, 7)), "does not divide"),
    (CameraGrid(azimuth=AngleRange(10, 0, 5)), "empty grid"),
    (CameraGrid(azimuth=AngleRange(0, 10, 0)), "step must be > 0"),
    (CameraGrid(distances=(0.5, -1.0)), "distance"),
    (CameraGrid(distances=()), "empty list"),
    (CameraGrid(elevation=AngleRange(0, 120, 5)), "[-90, 90]"),
    (CameraGrid(distance_mode="spiral"), "distance_mode"),
])
def test_bad_grids_raise_clear_errors(grid, message):
    with pytest.raises(SpecError, match=message.replace("[", r"\[").replace("]", r"\]")):
        camera_path(grid)


def test_poses_follow_the_path():
    path = camera_path(CameraGrid(azimuth=AngleRange(0, 10, 5), elevation=AngleRange(0, 0, 5)))
    R, t = path.poses()
    centres = -np.einsum("nji,nj->ni", R, t)
    np.testing.assert_allclose(np.degrees(np.arctan2(centres[:, 1], centres[:, 0])), path.azimuth, atol=1e-9)


@pytest.mark.parametrize("keys, message", [
    (dict(sampler="cube"), "camera.sampler: expected one of grid, sphere, so3"),
    (dict(sampler="sphere"), "camera.views: sampler 'sphere' needs views = N >= 1"),
    (dict(sampler="sphere", views=4, elevation_range=(50.0, 10.0)), "camera.elevation_range: expected [low, high]"),
    (dict(sampler="sphere", views=4, elevation_range=(0.0, 95.0)), "within [-90, 90] degrees"),
    (dict(sampler="so3", views=4, distance_range=(0.0, 1.0)), "camera.distance_range: values must be > 0 metres"),
    (dict(views=10), "camera.views: only for sampler = \"sphere\" or \"so3\""),
])
def test_bad_sampler_keys_name_the_key(keys, message):
    with pytest.raises(SpecError, match=message.replace("[", r"\[").replace("]", r"\]")):
        camera_path(CameraGrid(**keys))


@pytest.mark.parametrize("grid, message", [
    (CameraGrid(azimuth=AngleRange(0, 360, 5)), "camera.azimuth: 0..360 reaches a full turn, so 0 and 360 degrees "
                                                "are the same view, rendered twice; stop at 355"),
    (CameraGrid(azimuth=AngleRange(-180, 180, 30)), "camera.azimuth: -180..180 reaches a full turn.*stop at 150"),
    (CameraGrid(azimuth=AngleRange(0, 720, 90)), "camera.azimuth: 0..720 reaches a full turn"),
    (CameraGrid(roll=AngleRange(-180, 180, 45)), "camera.roll: -180..180 reaches a full turn.*stop at 135"),
    (CameraGrid(distances=(0.6, 0.7, 0.6)), r"camera.distances: \[0.6, 0.7, 0.6\] lists a distance twice"),
])
def test_a_grid_that_repeats_a_view_is_refused(grid, message):
    with pytest.raises(SpecError, match=message):
        camera_path(grid)
    assert len(camera_path(CameraGrid(azimuth=AngleRange(0, 355, 5)))) == 72 * 13   # the default walk: no repeat


def test_a_step_too_small_to_index_is_a_spec_error():
    # hypothesis found this one: 4.5e110 elevations overflowed int64 in value_at
    grid = CameraGrid(elevation=AngleRange(0.0, 1.0, 2.2273467270518148e-111))
    with pytest.raises(SpecError, match=r"camera.elevation: step .* gives over 1,000,000,000 values"):
        camera_path(grid)
    assert AngleRange(0.0, 360.0, 360 / (10**9 - 1)).count() == 10**9
