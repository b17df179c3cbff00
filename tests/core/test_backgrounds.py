"""spm_data.core.backgrounds: black, a colour, or seeded crops of a folder's images, composited
behind a premultiplied render."""

import cv2
import numpy as np
import pytest

from spm_data.core.backgrounds import background_image, composite
from spm_data.core.specs import parse_spec
from spm_data.errors import SpecError


def spec(tmp_path, background, width=40, height=30):
    return parse_spec(f'class = "cup"\n[image]\nwidth = {width}\nheight = {height}\n[background]\n{background}\n',
                      base_dir=str(tmp_path))


def test_black_is_none_and_a_colour_fills_the_frame(tmp_path):
    rng = np.random.default_rng(0)
    assert background_image(spec(tmp_path, 'kind = "black"'), rng) is None
    bg = background_image(spec(tmp_path, 'kind = "color"\ncolor = [0.2, 0.4, 1.0]'), rng)
    assert bg.shape == (30, 40, 3) and bg.dtype == np.uint8
    assert (bg.reshape(-1, 3) == [51, 102, 255]).all()                 # round(value * 255)


def test_images_are_seeded_crops_resized_to_the_frame(tmp_path):
    (tmp_path / "bg").mkdir()
    gradient = np.zeros((90, 120, 3), np.uint8)
    gradient[..., 0] = np.arange(120, dtype=np.uint8)[None, :] * 2     # red grows left to right
    gradient[..., 2] = 200
    cv2.imwrite(str(tmp_path / "bg" / "a.png"), cv2.cvtColor(gradient, cv2.COLOR_RGB2BGR))
    (tmp_path / "bg" / "notes.txt").write_text("not an image")
    s = spec(tmp_path, 'kind = "images"\nfolder = "bg"')
    a = background_image(s, np.random.default_rng(5))
    assert a.shape == (30, 40, 3) and a.dtype == np.uint8
    np.testing.assert_array_equal(a, background_image(s, np.random.default_rng(5)))   # same seed, same crop
    assert (a[..., 2] == 200).all() and (np.diff(a[..., 0].astype(int), axis=1) >= 0).all()  # a crop of it, upright
    assert a[..., 0].max() - a[..., 0].min() >= 60             # at least half the short side: a wide range of red
    crops = {background_image(s, np.random.default_rng(seed))[0, 0, 0] for seed in range(10)}
    assert len(crops) > 3                                      # other seeds, other crops


def test_a_bad_images_folder_is_a_spec_error(tmp_path):
    with pytest.raises(SpecError, match=r"^background.folder: no such folder .*missing$"):
        background_image(spec(tmp_path, 'kind = "images"\nfolder = "missing"'), np.random.default_rng(0))
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "notes.txt").write_text("x")
    with pytest.raises(SpecError, match=r"^background.folder: no images \(.png .jpg"):
        background_image(spec(tmp_path, 'kind = "images"\nfolder = "empty"'), np.random.default_rng(0))
    (tmp_path / "broken").mkdir()
    (tmp_path / "broken" / "a.png").write_bytes(b"not a png")
    with pytest.raises(SpecError, match=r"^background.folder: cannot read image .*a.png$"):
        background_image(spec(tmp_path, 'kind = "images"\nfolder = "broken"'), np.random.default_rng(0))


def test_composite_puts_the_premultiplied_render_over_the_background():
    rgb = np.array([[[40, 40, 40], [0, 0, 0], [100, 50, 0]]], np.uint8)    # premultiplied over black
    alpha = np.array([[0.25, 0.0, 1.0]], np.float32)
    background = np.full((1, 3, 3), 200, np.uint8)
    out = composite(rgb, alpha, background)
    assert out.dtype == np.uint8
    assert out.tolist() == [[[190, 190, 190], [200, 200, 200], [100, 50, 0]]]   # 40 + 0.75 * 200; background; object
    assert composite(rgb, alpha, None) is rgb                                    # black: the render as it is
    bright = composite(np.full((1, 1, 3), 250, np.uint8), np.array([[0.5]], np.float32), background[:, :1])
    assert bright.tolist() == [[[255, 255, 255]]]                                # clipped, not wrapped


def test_procedural_backgrounds_are_seeded_patterns():
    from spm_data.core.backgrounds import procedural_background

    for kind in ("color", "gradient", "checker", "noise"):
        a = procedural_background(kind, np.random.default_rng(3), 32, 48)
        assert a.shape == (32, 48, 3) and a.dtype == np.uint8
        np.testing.assert_array_equal(a, procedural_background(kind, np.random.default_rng(3), 32, 48))
        assert not np.array_equal(a, procedural_background(kind, np.random.default_rng(4), 32, 48))
    assert len(np.unique(procedural_background("color", np.random.default_rng(1), 8, 8).reshape(-1, 3), axis=0)) == 1
    assert len(np.unique(procedural_background("checker", np.random.default_rng(1), 64, 64).reshape(-1, 3),
                         axis=0)) == 2
    noise = procedural_background("noise", np.random.default_rng(1), 64, 64).astype(int)
    assert np.abs(np.diff(noise, axis=1)).mean() < 20 < noise.std()  # smooth, yet varied
    with pytest.raises(SpecError, match="unknown background kind"):
        procedural_background("plasma", np.random.default_rng(1), 8, 8)
