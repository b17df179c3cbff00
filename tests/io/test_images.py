"""spm_data.io.images: image references (files, zip and tar members), PNM by hand, 8- and
16-bit images, and every unreadable image an ImageError naming it."""

import io
import os
import tarfile
import zipfile

import numpy as np
import pytest

from spm_data.io.images import ImageError, decode_image, from_16_bit, image_size, parse_pnm, read_bytes
from tests.helpers import coil_image, png_bytes, ppm16


def test_pnm_parser_is_strict_about_truncation():
    img = coil_image(1, 0)
    np.testing.assert_array_equal(parse_pnm(ppm16(img)), img)
    from spm_data.io.images import ImageError

    with pytest.raises(ImageError, match="truncated"):
        parse_pnm(ppm16(img)[:-10])


def test_parse_pnm_grey_8_bit_and_bad_headers():
    grey = np.arange(12, dtype=np.uint8).reshape(3, 4) * 20
    data = b"P5 4 3\n# a comment\n255\n" + grey.tobytes()
    np.testing.assert_array_equal(parse_pnm(data), np.repeat(grey[..., None], 3, axis=2))
    with pytest.raises(ImageError, match="not a binary PNM image"):
        parse_pnm(b"P3 4 3 255\n" + grey.tobytes())
    with pytest.raises(ImageError, match=r"out of range \(0x3, maxval 255\)"):
        parse_pnm(b"P5 0 3 255\n")


def test_references_to_files_and_archive_members(tmp_path):
    (tmp_path / "a.png").write_bytes(png_bytes(coil_image(1, 0)))
    with zipfile.ZipFile(tmp_path / "a.zip", "w") as zf:
        zf.writestr("dir/b.png", png_bytes(coil_image(2, 0)))
    with tarfile.open(tmp_path / "a.tar", "w") as tf:
        data = ppm16(coil_image(3, 0))
        info = tarfile.TarInfo("c.ppm")
        info.size = len(data)
        tf.addfile(info, io.BytesIO(data))
    for ref, obj in ((str(tmp_path / "a.png"), 1), (f"zip:{tmp_path / 'a.zip'}::dir/b.png", 2),
                     (f"tar:{tmp_path / 'a.tar'}::c.ppm", 3)):
        np.testing.assert_array_equal(decode_image(read_bytes(ref), ref), coil_image(obj, 0))
        assert image_size(ref) == (128, 128)
    with pytest.raises(ImageError, match=r"::nope.png: cannot read \("):
        read_bytes(f"zip:{tmp_path / 'a.zip'}::nope.png")
    with pytest.raises(ImageError, match=r"none.png: no such file$"):
        read_bytes(str(tmp_path / "none.png"))
    os.mkfifo(tmp_path / "fifo.png")   # refused without waiting for a writer (Path.read_bytes hung)
    with pytest.raises(ImageError, match=r"fifo.png: is a FIFO, not a regular file; give an image file$"):
        read_bytes(str(tmp_path / "fifo.png"))


def test_unreadable_data_is_an_image_error_naming_the_image():
    with pytest.raises(ImageError, match="^x.png: empty file$"):
        decode_image(b"", "x.png")
    with pytest.raises(ImageError, match=r"^y.png: not a readable image \(unknown format, or a truncated header\)$"):
        decode_image(b"not an image at all", "y.png")
    whole = png_bytes(coil_image(5, 0))
    with pytest.raises(ImageError, match=r"^z.png: not a readable image \(truncated or corrupt: "):
        decode_image(whole[: len(whole) // 2], "z.png")


def test_16_bit_samples_scale_by_a_fixed_257():
    values = np.array([0, 128, 129, 257, 32896, 65535, 70000, -5])
    assert from_16_bit(values).tolist() == [0, 0, 1, 1, 128, 255, 255, 0]   # round(v / 257), clipped first
    assert from_16_bit(np.arange(256) * 257).tolist() == list(range(256))    # v * 257 -> v exactly


def test_alpha_masks_from_rgba_grey_alpha_and_palette_transparency():
    from PIL import Image

    from spm_data.io.images import decode_alpha, image_header

    def png(img, **kw):
        buf = io.BytesIO()
        img.save(buf, "PNG", **kw)
        return buf.getvalue()

    alpha = np.zeros((6, 5), np.uint8)
    alpha[2:4, 1:3] = 255
    rgba = png(Image.fromarray(np.dstack([np.full((6, 5, 3), 90, np.uint8), alpha]), "RGBA"))
    la = png(Image.fromarray(np.dstack([np.full((6, 5), 90, np.uint8), alpha]), "LA"))
    index = np.where(alpha > 0, 1, 0).astype(np.uint8)
    palette = png(Image.fromarray(index, "P"), transparency=0)
    for data in (rgba, la, palette):
        np.testing.assert_array_equal(decode_alpha(data, "x.png") >= 128, alpha > 0)
    opaque = png(Image.fromarray(np.zeros((6, 5, 3), np.uint8)))
    with pytest.raises(ImageError, match=r"^x.png: no alpha channel"):
        decode_alpha(opaque, "x.png")
    import tempfile
    with tempfile.TemporaryDirectory() as folder:
        for name, data, has in (("a.png", rgba, True), ("b.png", opaque, False)):
            with open(f"{folder}/{name}", "wb") as fh:
                fh.write(data)
            assert image_header(f"{folder}/{name}") == (5, 6, has)
