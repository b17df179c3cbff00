import numpy as np
import pytest

from spm_data.core.paths import AngleRange, CameraGrid, camera_path
from spm_data.core.walks import snake_digits, snake_order


def test_snake_order_visits_every_cell_once_with_unit_moves():
    idx = snake_order([3, 4, 5])
    assert len({tuple(r) for r in idx}) == 60
    assert np.all(np.abs(np.diff(idx, axis=0)).sum(axis=1) == 1)



# --------------------------------------------------------------------------- lazy path

def materialised_walk(grid):
    """The walk as camera_path built it before it was lazy: every point as arrays."""
    az, el, rl = (r.values() for r in (grid.azimuth, grid.elevation, grid.roll))
    distances = np.asarray(grid.distances, dtype=np.float64)
    if grid.distance_mode == "grid":
        idx = snake_order([len(distances), len(rl), len(el), len(az)])
        dist, idx = distances[idx[:, 0]], idx[:, 1:]
    else:
        idx = snake_order([len(rl), len(el), len(az)])
        dist = distances[np.arange(len(idx)) % len(distances)]
    return {"azimuth": az[idx[:, 2]], "elevation": el[idx[:, 1]], "roll": rl[idx[:, 0]], "distance": dist}


SMALL_GRIDS = [
    CameraGrid(),
    CameraGrid(distance_mode="grid"),
    CameraGrid(azimuth=AngleRange(0, 10, 5), elevation=AngleRange(-30, 30, 7.5), roll=AngleRange(-10, 10, 2.5),
               distances=(0.5, 0.6, 0.9, 1.1)),
    CameraGrid(azimuth=AngleRange(0, 10, 5), elevation=AngleRange(-30, 30, 7.5), roll=AngleRange(-10, 10, 2.5),
               distances=(0.5, 0.6), distance_mode="grid", look_at=(0.1, 0.2, 0.3)),
    CameraGrid(azimuth=AngleRange(3.3, 3.3, 1), elevation=AngleRange(0.1, 0.7, 0.1), distances=(1.0,)),
    CameraGrid(azimuth=AngleRange(0, 359.9, 0.1), elevation=AngleRange(-0.3, 0.3, 0.1), distances=(0.6, 0.7, 0.8)),
]


@pytest.mark.parametrize("grid", SMALL_GRIDS)
def test_lazy_path_is_the_materialised_walk_bit_for_bit(grid):
    path, walk = camera_path(grid), materialised_walk(grid)
    assert len(path) == len(walk["azimuth"])
    for name, values in walk.items():
        assert getattr(path, name).tobytes() == values.tobytes(), name
    pick = np.random.default_rng(0).integers(0, len(path), 40)
    points = path.at(pick)
    for name, values in walk.items():
        assert getattr(points, name).tobytes() == values[pick].tobytes(), name
    from spm_data.core.poses import camera_poses

    R, t = path.poses(pick)
    R0, t0 = camera_poses(walk["azimuth"][pick], walk["elevation"][pick], walk["roll"][pick],
                          walk["distance"][pick], grid.look_at)
    assert R.tobytes() == R0.tobytes() and t.tobytes() == t0.tobytes()


@pytest.mark.parametrize("sizes", [[1], [5], [3, 4], [2, 1, 3], [3, 4, 5], [2, 3, 2, 4], [1, 1, 1]])
def test_snake_digits_are_the_rows_of_snake_order(sizes):
    order = snake_order(sizes)
    digits = snake_digits(np.arange(len(order)), sizes)
    np.testing.assert_array_equal(np.stack(digits, axis=1), order)


def test_path_indexing_like_an_array():
    path = camera_path(CameraGrid(azimuth=AngleRange(0, 20, 5), elevation=AngleRange(0, 10, 5)))
    az = path.azimuth
    np.testing.assert_array_equal(path.at(slice(2, 9, 3)).azimuth, az[2:9:3])
    np.testing.assert_array_equal(path.at(np.array([-1, 0, -15])).azimuth, az[[-1, 0, -15]])
    np.testing.assert_array_equal(path.at(az > 10).azimuth, az[az > 10])
    assert path.at(np.zeros(0, np.int64)).azimuth.shape == (0,)
    with pytest.raises(IndexError, match="out of bounds"):
        path.at(np.array([15]))


def test_a_huge_grid_is_a_path_without_arrays():
    import tracemalloc

    grid = CameraGrid(azimuth=AngleRange(0, 359.9999, 0.0001), elevation=AngleRange(0, 60, 0.0001),
                      roll=AngleRange(-1, 1, 0.01))
    tracemalloc.start()
    try:
        path = camera_path(grid)
        n = len(path)
        last = path.at(np.array([0, 1, n - 1]))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert n == 3_600_000 * 600_001 * 201 * 1
    assert peak < 1_000_000
    # The last roll (digit 200, even) walks elevation forwards to its last row (600000, even),
    # which walks azimuth forwards: the last point is the grid's far corner.
    np.testing.assert_array_equal(last.azimuth, [0.0, 0.0001, 0.0001 * 3_599_999])
    np.testing.assert_array_equal(last.elevation, [0.0, 0.0, 60.0])
    np.testing.assert_array_equal(last.roll, [-1.0, -1.0, 1.0])


# --------------------------------------------------------------------------- samplers

def sampled(**keys):
    return camera_path(CameraGrid(**keys), seed=11)


def test_sphere_views_stay_in_their_zone_uniform_over_its_area():
    path = sampled(sampler="sphere", views=20_000, elevation_range=(10.0, 50.0), roll_range=(-20.0, 20.0),
                   distance_range=(0.5, 0.9))
    p = path.at()
    assert len(path) == 20_000
    assert 10.0 <= p.elevation.min() < 10.5 and 49.5 < p.elevation.max() <= 50.0
    assert -20.0 <= p.roll.min() < -19.5 and 19.5 < p.roll.max() <= 20.0
    assert 0.0 <= p.azimuth.min() < 1.0 and 359.0 < p.azimuth.max() < 360.0
    assert 0.5 <= p.distance.min() and p.distance.max() <= 0.9
    # Uniform on the sphere's zone: sin(elevation) uniform between sin 10 and sin 50, so the
    # median elevation is the one halfway in sin (28.6 degrees), not halfway in angle (30).
    halfway = np.degrees(np.arcsin((np.sin(np.radians(10)) + np.sin(np.radians(50))) / 2))
    assert abs(np.median(p.elevation) - halfway) < 0.6 and abs(halfway - 30.0) > 1.0


def test_so3_views_are_uniform_rotations_with_roll_over_the_full_circle():
    path = sampled(sampler="so3", views=20_000, distance_range=(0.7, 0.7))
    p = path.at()
    assert p.roll.min() < -179.0 and p.roll.max() > 179.0
    assert abs(np.std(p.roll) - 360 / np.sqrt(12)) < 2.0        # uniform over 360 degrees: std 103.9
    assert p.elevation.min() < -85.0 and p.elevation.max() > 85.0
    R, t = path.poses()
    # The mean of Haar-uniform rotations is the zero matrix; a grid walk's is not.
    assert np.abs(R.mean(axis=0)).max() < 0.02
    assert np.abs(camera_path(CameraGrid()).poses()[0].mean(axis=0)).max() > 0.3
    np.testing.assert_allclose(np.linalg.norm(t, axis=1), 0.7)


def test_sampled_views_depend_on_seed_and_index_only():
    path = sampled(sampler="so3", views=1000)
    whole = path.at()
    some = path.at(np.array([999, 3, 500]))
    np.testing.assert_array_equal(some.azimuth, whole.azimuth[[999, 3, 500]])
    np.testing.assert_array_equal(some.roll, whole.roll[[999, 3, 500]])
    other = camera_path(CameraGrid(sampler="so3", views=1000), seed=12).at()
    assert not np.allclose(other.azimuth, whole.azimuth)
    longer = sampled(sampler="so3", views=5000).at(slice(0, 1000))   # more views: the first ones stay
    np.testing.assert_array_equal(longer.elevation, whole.elevation)
