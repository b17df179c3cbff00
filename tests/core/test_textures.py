"""spm_data.core.textures: seeded, high-contrast procedural textures (a 3 x 2 atlas of tiles)."""

import numpy as np

from spm_data.core.textures import SHAPE, TILE, procedural_texture


def test_the_texture_is_a_seeded_rgb_atlas():
    a = procedural_texture(np.random.default_rng(3))
    assert SHAPE == (2 * TILE, 3 * TILE, 3) == (512, 768, 3)
    assert a.shape == SHAPE and a.dtype == np.uint8
    np.testing.assert_array_equal(procedural_texture(np.random.default_rng(3)), a)       # same state, same image
    assert (procedural_texture(np.random.default_rng(4)) != a).mean() > 0.5             # another seed: another


def test_it_draws_from_the_generator_it_is_given():
    rng = np.random.default_rng(7)
    first, second = procedural_texture(rng), procedural_texture(rng)
    assert (first != second).mean() > 0.5            # the generator moved on


def test_the_background_is_one_colour_and_shapes_cover_much_of_it():
    blank = procedural_texture(np.random.default_rng(0), shapes=0)
    colours = np.unique(blank.reshape(-1, 3), axis=0)
    assert len(colours) == 1
    dark, light = colours[0].max() < 90, colours[0].min() >= 150       # dark 0..89 or light 150..255 per channel
    assert dark or light
    busy = procedural_texture(np.random.default_rng(0))
    covered = (busy != colours[0]).any(axis=2).mean()
    assert 0.3 < covered < 1.0 and busy.std() > 40                      # high contrast for SIFT
