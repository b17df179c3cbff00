import numpy as np
import trimesh

from spm_model.bench.surface_metrics import ObjectModel, object_model, summarise_surface, surface_errors

A, B, C = 0.1, 0.05, 0.05
CORNERS = np.array([[x, y, z] for x in (-A, A) for y in (-B, B) for z in (-C, C)])
HALF_TURN_Z = np.diag([-1.0, -1.0, 1.0])
K = np.array([[[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]])


def corner_model(symmetries):
    return ObjectModel(points=CORNERS, diameter=float(2 * np.sqrt(A * A + B * B + C * C)),
                       symmetries=np.array(symmetries))


def errors(model, pred_R, pred_t, true_R=np.eye(3), true_t=(0, 0, 1.0)):
    return surface_errors(np.array([pred_R]), np.array([pred_t], float), np.array([true_R]),
                          np.array([true_t], float), K, model, 640)


def test_add_s_forgives_a_symmetric_turn_that_add_counts():
    e = errors(corner_model([np.eye(3)]), HALF_TURN_Z, (0, 0, 1.0))
    assert np.isclose(e["add"][0], 2 * np.sqrt(A * A + B * B))     # every corner moves to the opposite one
    assert np.isclose(e["adds"][0], 0.0)                            # ...which is another corner
    assert np.isclose(e["mssd"][0], 2 * np.sqrt(A * A + B * B))     # no symmetry declared: counted
    symmetric = errors(corner_model([np.eye(3), HALF_TURN_Z]), HALF_TURN_Z, (0, 0, 1.0))
    assert np.isclose(symmetric["mssd"][0], 0.0) and np.isclose(symmetric["mspd"][0], 0.0)


def test_mspd_is_the_largest_reprojection_shift_in_pixels():
    # 1 cm sideways at 1 m: a point at depth z moves f * 0.01 / z pixels; the nearest corners (z = 1 - C) most.
    e = errors(corner_model([np.eye(3)]), np.eye(3), (0.01, 0, 1.0))
    assert np.isclose(e["mspd"][0], 500 * 0.01 / (1 - C))
    assert np.isclose(e["add"][0], 0.01) and np.isclose(e["mssd"][0], 0.01)
    missing = surface_errors(np.full((1, 3, 3), np.nan), np.full((1, 3), np.nan), np.eye(3)[None],
                             np.array([[0, 0, 1.0]]), K, corner_model([np.eye(3)]), 640)
    assert np.isnan(missing["add"][0])


def test_recalls_use_ten_percent_of_the_diameter_and_bop_thresholds():
    d = 0.2
    errors_ = {"add": np.array([0.019, 0.021, np.nan]), "adds": np.array([0.001, 0.001, np.nan]),
               "mssd": np.array([0.009, 0.05, np.nan]), "mspd": np.array([4.0, 26.0, np.nan]),
               "diameter": np.full(3, d), "symmetric": np.array([0.0, 1.0, 0.0]), "mspd_scale": np.ones(3)}
    s = summarise_surface(errors_)
    assert np.isclose(s["add_recall"], 100 / 3)            # 0.019 < 0.02 only; a missing estimate fails
    assert np.isclose(s["adds_recall"], 200 / 3)
    assert np.isclose(s["add_s_recall"], 200 / 3)          # ADD for the first, ADD-S for the symmetric second
    # MSSD 0.009 = 4.5% of d: under every threshold 5..50%; 0.05 = 25%: under 6 of 10 (25 itself is not under).
    assert np.isclose(s["ar_mssd"], (100 + 50) / 3)
    assert np.isclose(s["ar_mspd"], (100 + 50) / 3)        # 4 px under all of 5..50; 26 px under 30..50 (5 of 10)
    assert s["frames"] == 3 and np.isclose(s["mspd_median_px"], 15.0)


def test_symmetries_are_found_from_the_geometry():
    box = object_model(trimesh.creation.box(extents=(0.3, 0.2, 0.1)))
    assert len(box.symmetries) == 4                        # identity and three half-turns
    assert np.isclose(box.diameter, np.sqrt(0.3 ** 2 + 0.2 ** 2 + 0.1 ** 2))
    cylinder = object_model(trimesh.creation.cylinder(radius=0.1, height=0.3, sections=72))
    turns = [np.degrees(np.arctan2(S[1, 0], S[0, 0])) for S in cylinder.symmetries if np.isclose(S[2, 2], 1)]
    assert len(turns) == 36                                # every 10-degree turn about its axis, identity included
    lopsided = trimesh.util.concatenate([trimesh.creation.box(extents=(0.3, 0.2, 0.1)),
                                         trimesh.creation.icosphere(radius=0.05).apply_translation((0.15, 0.05, 0))])
    assert len(object_model(lopsided).symmetries) == 1
