"""[randomize]: per-frame draws, deterministic, within their ranges, validated."""

import numpy as np
import pytest

from spm_data.core.randomize import STREAMS, fixed_light_rotations, frame_draws, frame_rng, frame_stream, max_lights
from spm_data.core.specs import parse_spec
from spm_data.errors import SpecError
from spm_data.render.base import spec_intrinsics

RANDOM = """class = "cup"
[randomize]
lights = [1, 4]
light_cone = 30.0
light_strength = [0.5, 2.0]
light_color = [0.6, 1.0]
ambient = [0.1, 0.3]
base_color = [0.8, 1.2]
roughness = [0.2, 0.6]
metallic = [0.0, 0.5]
backgrounds = ["gradient", "checker"]
focal = [0.95, 1.05]
principal_point = 3.0
"""


def test_without_the_table_the_draws_are_the_specs_fixed_values():
    spec = parse_spec('class = "cup"\n[lighting]\nlights = 2\nstrength = 1.2\nambient = 0.25')
    d = frame_draws(spec, 0, 7)
    np.testing.assert_array_equal(d.K, spec_intrinsics(spec))
    np.testing.assert_array_equal(d.light_rotations, fixed_light_rotations(2))
    assert list(d.light_strengths) == [1.2, 1.2] and d.ambient == 0.25 and d.background == "black"
    assert (d.roughness, d.metallic, list(d.base_color)) == (0.9, 0.0, [1.0, 1.0, 1.0])
    assert not spec.randomize.enabled


def test_draws_stay_in_their_ranges_and_the_lights_in_their_cone():
    spec = parse_spec(RANDOM)
    K0 = spec_intrinsics(spec)
    counts, kinds = set(), set()
    for i in range(300):
        d = frame_draws(spec, i % 3, i)
        n = len(d.light_strengths)
        counts.add(n)
        kinds.add(d.background)
        assert 1 <= n <= 4 and d.light_colors.shape == (n, 3) and d.light_rotations.shape == (n, 3, 3)
        assert np.all((0.5 <= d.light_strengths) & (d.light_strengths <= 2.0))
        assert np.all((0.6 <= d.light_colors) & (d.light_colors <= 1.0))
        assert 0.1 <= d.ambient <= 0.3 and 0.2 <= d.roughness <= 0.6 and 0.0 <= d.metallic <= 0.5
        assert np.all((0.8 <= d.base_color) & (d.base_color <= 1.2))
        assert 0.95 <= d.K[0, 0] / K0[0, 0] <= 1.05 and d.K[0, 0] == d.K[1, 1]
        assert np.all(np.abs(d.K[:2, 2] - K0[:2, 2]) <= 3.0)
        forward = d.light_directions() @ np.array([0.0, 0.0, 1.0])  # OpenCV: the view axis is +z
        assert np.all(np.degrees(np.arccos(np.clip(forward, -1, 1))) <= 30.0 + 1e-9)
    assert counts == {1, 2, 3, 4} and kinds == {"gradient", "checker"}
    assert max_lights(spec) == 4


def test_a_frames_draws_depend_on_the_frame_alone_and_each_key_has_its_own_stream():
    spec = parse_spec(RANDOM)
    a, b = frame_draws(spec, 1, 5), frame_draws(spec, 1, 5)
    np.testing.assert_array_equal(a.light_colors, b.light_colors)
    assert a.roughness == b.roughness
    assert frame_draws(spec, 1, 6).roughness != a.roughness
    fewer = parse_spec(RANDOM.replace("metallic = [0.0, 0.5]\n", ""))
    c = frame_draws(fewer, 1, 5)
    assert c.roughness == a.roughness and c.metallic == 0.0
    np.testing.assert_array_equal(c.light_rotations, a.light_rotations)


def test_labels_hold_the_draws_with_zero_rows_for_missing_lights():
    spec = parse_spec(RANDOM)
    d = next(d for i in range(50) if len((d := frame_draws(spec, 0, i)).light_strengths) == 2)
    labels = d.labels(4)
    assert labels["lights"].shape == (4, 7) and labels["lights"].dtype == np.float32
    assert not labels["lights"][2:].any()
    np.testing.assert_allclose(np.linalg.norm(labels["lights"][:2, :3], axis=1), 1.0, rtol=1e-6)
    np.testing.assert_allclose(labels["material"], [*d.base_color, d.roughness, d.metallic], rtol=1e-6)


def test_the_fingerprint_changes_only_when_the_table_is_there():
    plain = parse_spec('class = "cup"')
    assert parse_spec('class = "cup"\n[randomize]\n').fingerprint() == plain.fingerprint()
    assert parse_spec(RANDOM).fingerprint() != plain.fingerprint()


@pytest.mark.parametrize("body, message", [
    ("lights = [3, 1]", "randomize.lights: expected \\[low, high\\]"),
    ("lights = [1.5, 2]", "randomize.lights: expected whole"),
    ("lights = [1, 9]", "randomize.lights: values must be within"),
    ("roughness = [0.2, 1.5]", "randomize.roughness"),
    ("light_cone = 120", "randomize.light_cone"),
    ("principal_point = -1", "randomize.principal_point"),
    ("backgrounds = [\"plasma\"]", "randomize.backgrounds: 'plasma'"),
    ("backgrounds = [\"images\"]", "needs background.folder"),
    ("colour = [0, 1]", "randomize.colour: unknown key"),
])
def test_bad_values_name_their_key(body, message):
    with pytest.raises(SpecError, match=message):
        parse_spec(f'class = "cup"\n[randomize]\n{body}\n')


def test_workbench_cannot_honour_random_lights():
    with pytest.raises(SpecError, match="Workbench"):
        parse_spec('class = "cup"\n[render.blender]\nengine = "workbench"\n[randomize]\nlights = [1, 2]\n')


def test_a_spec_without_lights_still_has_a_lights_field():
    from spm_data.core.randomize import lights_width

    spec = parse_spec('class = "cup"\n[randomize]\nlights = [0, 0]\n')
    d = frame_draws(spec, 0, 0)
    assert len(d.light_strengths) == 0 and lights_width(spec) == 1
    assert d.labels(lights_width(spec))["lights"].shape == (1, 7) and not d.labels(1)["lights"].any()


def test_workbench_cannot_honour_a_base_colour():
    with pytest.raises(SpecError, match="randomize.base_color: Workbench"):
        parse_spec('class = "cup"\n[render.blender]\nengine = "workbench"\n[randomize]\nbase_color = [0.5, 1]\n')


def test_the_named_streams_keep_the_numbers_every_shard_was_made_with():
    """frame_rng's entropy is [seed, crc32(class), instance, view, stream number(, crc32(key))]: the
    numbers below are those of the shards made before the streams had names (same seed, same bytes)."""
    import zlib

    spec = parse_spec('class = "cup"\nseed = 7\n[mesh]\ngenerator = "cup"\n')
    assert STREAMS == {"background": 1, "draws": 2}
    crc = zlib.crc32(b"cup")
    expect = np.random.default_rng([7, crc, 2, 5, 1]).random(4)
    assert np.array_equal(frame_rng(spec, 2, 5, "background").random(4), expect)
    keyed = np.random.default_rng([7, crc, 2, 5, 2, zlib.crc32(b"lights")]).random(4)
    assert np.array_equal(frame_stream(spec, 2, 5, "lights").random(4), keyed)
    assert np.array_equal(frame_rng(spec, 2, 5, "draws", "lights").random(4), keyed)
    with pytest.raises(KeyError):
        frame_rng(spec, 2, 5, "noise")
