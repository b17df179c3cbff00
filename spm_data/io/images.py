"""Reading images robustly: files or archive members, 8- and 16-bit, PNM by hand.

A reference is a path, ``zip:ARCHIVE::MEMBER`` or ``tar:ARCHIVE::MEMBER``. What
cannot be read (missing, truncated, foreign, a decompression bomb) is an
:class:`ImageError` naming the image, never a traceback. Importers and
``spm predict`` read through here.
"""

from __future__ import annotations

import io
import re
import tarfile
import zipfile
from contextlib import contextmanager

import numpy as np

from spm_data.errors import ImageError, SpmError, one_line  # noqa: F401 (SpmError: re-exported)
from spm_data.io.files import read_regular_file

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".ppm", ".pgm", ".bmp", ".tif", ".tiff")
# An image file larger than this is refused before it is read (decoded sizes are bounded by
# Pillow's decompression-bomb limit, PIL.Image.MAX_IMAGE_PIXELS, checked from the header).
MAX_IMAGE_BYTES = 256 * 2**20


def read_image_file(path, limit: int = MAX_IMAGE_BYTES) -> bytes:
    """The bytes of an image file; ImageError with the reason alone for a missing file, a
    folder, anything that is not a regular file (a FIFO, a device such as /dev/zero: refused
    without reading or waiting), and a file over ``limit`` bytes (refused before reading)."""
    try:
        return read_regular_file(path, limit)
    except FileNotFoundError:
        raise ImageError("no such file") from None
    except OSError as exc:
        raise ImageError(f"cannot read ({exc.strerror or exc})") from None
    except ValueError as exc:
        reason = str(exc)
        if reason == "is a folder":
            raise ImageError("is a folder, not an image file") from None
        if reason.startswith("is "):
            raise ImageError(f"{reason}, not a regular file; give an image file") from None
        raise ImageError(f"{reason.replace('the limit', 'the image file limit')} "
                         "(spm_data.io.images.MAX_IMAGE_BYTES); downscale or recompress the image") from None


def read_bytes(ref: str) -> bytes:
    """The bytes behind an image reference (a file, or a member of a zip or tar archive)."""
    try:
        if ref.startswith("zip:"):
            archive, member = ref[4:].split("::", 1)
            with zipfile.ZipFile(archive) as zf:
                return zf.read(member)
        if ref.startswith("tar:"):
            archive, member = ref[4:].split("::", 1)
            with tarfile.open(archive) as tf:
                handle = tf.extractfile(member)
                if handle is None:
                    raise ImageError(f"{ref}: not a file in the archive")
                return handle.read()
        try:   # a FIFO or a device is refused without reading or waiting (it hung), and said as such
            return read_image_file(ref)
        except ImageError as exc:
            raise ImageError(f"{ref}: {exc}") from None
    except (OSError, KeyError, zipfile.BadZipFile, tarfile.TarError) as exc:
        raise ImageError(f"{ref}: cannot read ({exc})") from None


def parse_pnm(data: bytes) -> np.ndarray:
    """Netpbm P5/P6 (binary grey/RGB), 8 or 16 bits, with comments and any whitespace
    in the header. Returns (H, W, 3) uint8 (16-bit values scaled by 255 / maxval)."""
    fields, pos = [], 0
    while len(fields) < 4:
        while pos < len(data) and data[pos:pos + 1].isspace():
            pos += 1
        if data[pos:pos + 1] == b"#":  # a comment runs to the end of the line
            end = data.find(b"\n", pos)
            pos = len(data) if end < 0 else end + 1
            continue
        m = re.match(rb"\S+", data[pos:])
        if not m:
            raise ImageError("PNM header ends early")
        fields.append(m.group(0))
        pos += len(m.group(0))
    pos += 1  # exactly one whitespace byte before the raster
    magic = fields[0]
    if magic not in (b"P5", b"P6"):
        raise ImageError(f"not a binary PNM image (magic {magic[:4]!r})")
    try:
        w, h, maxval = (int(x) for x in fields[1:])
    except ValueError:
        raise ImageError("PNM header has a non-number size") from None
    if w <= 0 or h <= 0 or not 0 < maxval < 65536:
        raise ImageError(f"PNM header out of range ({w}x{h}, maxval {maxval})")
    from PIL import Image

    if Image.MAX_IMAGE_PIXELS and w * h > Image.MAX_IMAGE_PIXELS:  # the limit Pillow applies to other formats
        raise ImageError(_bomb_reason(f"({w * h} pixels)"))
    channels = 3 if magic == b"P6" else 1
    dtype = np.dtype(">u2") if maxval > 255 else np.dtype(np.uint8)
    need = w * h * channels * dtype.itemsize
    if len(data) - pos < need:
        raise ImageError(f"PNM image is truncated ({len(data) - pos} of {need} bytes)")
    raster = np.frombuffer(data, dtype=dtype, count=w * h * channels, offset=pos).reshape(h, w, channels)
    if maxval != 255:
        raster = np.round(raster.astype(np.float64) * (255.0 / maxval))
    raster = raster.astype(np.uint8)
    return np.repeat(raster, 3, axis=2) if channels == 1 else raster


def _bomb_reason(exc) -> str:
    from PIL import Image

    m = re.search(r"\((\d+) pixels\)", str(exc))
    size = f"{int(m.group(1)):,} pixels" if m else "the image"
    return (f"{size} is over the decompression-bomb limit of {Image.MAX_IMAGE_PIXELS:,} pixels "
            "(Pillow's PIL.Image.MAX_IMAGE_PIXELS); downscale the image")


@contextmanager
def _open_image(data: bytes):
    """Pillow's image of ``data``, decompression bombs (its error and its warning) and
    foreign or truncated data as ImageError with a reason (no file name)."""
    import warnings

    from PIL import Image, UnidentifiedImageError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            with Image.open(io.BytesIO(data)) as img:
                yield img
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
        raise ImageError(_bomb_reason(exc)) from None
    except UnidentifiedImageError:
        raise ImageError("not a readable image (unknown format, or a truncated header)") from None
    except (OSError, SyntaxError, ValueError, EOFError) as exc:
        raise ImageError(f"not a readable image (truncated or corrupt: {one_line(exc)})") from None


def _tile_rawmode(img) -> str:
    """The raw mode Pillow will decode the file's pixels from ("RGB;16B": 16-bit colour); "" if unknown."""
    try:
        args = img.tile[0].args if hasattr(img.tile[0], "args") else img.tile[0][3]
        return str(args[0] if isinstance(args, tuple) else args)
    except (IndexError, TypeError, AttributeError):
        return ""


def from_16_bit(values: np.ndarray) -> np.ndarray:
    """16-bit samples -> uint8 by the fixed scale round(value / 257) (65535 -> 255, v * 257 -> v):
    never stretched per image, so an 8-bit image and its 16-bit copy give the same pixels."""
    return np.round(np.clip(np.asarray(values, dtype=np.float64), 0, 65535) / 257.0).astype(np.uint8)


def decode_bytes(data: bytes, mode: str = "RGB") -> np.ndarray:
    """:func:`decode_image` without the name: ImageError's message is the reason alone."""
    if not data:
        raise ImageError("empty file")
    if data[:2] in (b"P5", b"P6") and mode == "RGB":
        return parse_pnm(data)
    with _open_image(data) as img:
        rawmode = _tile_rawmode(img)
        img.load()  # decodes everything: a truncated file raises here
        if mode != "RGB":
            return np.asarray(img)
        if img.mode in ("I;16", "I;16B", "I;16L", "I;16N", "I"):  # 16-bit grey (32-bit "I": clipped to 16)
            return np.repeat(from_16_bit(np.asarray(img))[..., None], 3, axis=2)
        if img.mode in ("RGB", "RGBA") and ";16" in rawmode:
            # Pillow keeps 16-bit colour's high byte; OpenCV reads all 16 bits, scaled as grey is.
            import cv2

            full = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
            if full is not None and full.dtype == np.uint16 and full.ndim == 3 and full.shape[2] in (3, 4) \
                    and full.shape[:2] == (img.height, img.width):
                return from_16_bit(full[..., 2::-1])
        return np.asarray(img.convert("RGB"), dtype=np.uint8)


def decode_image(data: bytes, name: str = "", mode: str = "RGB") -> np.ndarray:
    """(H, W, 3) uint8 RGB (mode "RGB") or (H, W) array as stored ("raw", e.g. uint16
    depth or a mask). 16-bit images (grey, colour, PNM) become 8 bits by round(value / 257).
    Empty, truncated or foreign data and images over Pillow's decompression-bomb limit
    raise ImageError ("NAME: reason")."""
    try:
        return decode_bytes(data, mode)
    except ImageError as exc:
        raise ImageError(f"{name}: {exc}") from None


def image_size(ref: str) -> tuple[int, int]:
    """(width, height) from the header only (image_header)."""
    return image_header(ref)[:2]


def _has_alpha(img) -> bool:
    return img.mode in ("RGBA", "LA", "PA", "RGBa", "La") or "transparency" in img.info


def image_header(ref: str, data: bytes | None = None) -> tuple[int, int, bool]:
    """(width, height, whether the image has an alpha channel or a transparent colour), from the
    header only; ImageError ("REF: reason") for what is not a readable image. ``data``: the
    reference's bytes, when the caller has them."""
    data = read_bytes(ref) if data is None else data
    try:
        if data[:2] in (b"P5", b"P6"):
            img = parse_pnm(data)
            return img.shape[1], img.shape[0], False
        if not data:
            raise ImageError("empty file")
        with _open_image(data) as img:
            return img.size[0], img.size[1], _has_alpha(img)
    except ImageError as exc:
        raise ImageError(f"{ref}: {exc}") from None


def decode_alpha(data: bytes, name: str = "") -> np.ndarray:
    """(H, W) uint8: the image's opacity (its alpha channel, or its transparent colour, through
    Pillow's RGBA conversion); ImageError ("NAME: reason") when it has neither."""
    try:
        if not data:
            raise ImageError("empty file")
        with _open_image(data) as img:
            if not _has_alpha(img):
                raise ImageError("no alpha channel (or transparent colour) to take the mask from")
            img.load()
            return np.asarray(img.convert("RGBA"), dtype=np.uint8)[..., 3]
    except ImageError as exc:
        raise ImageError(f"{name}: {exc}") from None


def image_sizes(refs) -> dict:
    """{ref: (width, height)} of image references, or the ImageError of each that cannot be read;
    every archive is opened once (a member at a time would decompress a .tar.gz again per image)."""
    out, by_archive = {}, {}
    for ref in refs:
        if ref.startswith(("zip:", "tar:")):
            archive, member = ref[4:].split("::", 1)
            by_archive.setdefault((ref[:3], archive), []).append((ref, member))
        else:
            out[ref] = _size_or_error(ref, None)
    for (kind, archive), members in by_archive.items():
        try:
            with (zipfile.ZipFile(archive) if kind == "zip" else tarfile.open(archive)) as handle:
                wanted = dict((member, ref) for ref, member in members)
                if kind == "zip":
                    for member, ref in wanted.items():
                        out[ref] = _size_or_error(ref, lambda m=member: handle.read(m))
                else:
                    for info in handle:  # one pass over the stream
                        if info.name in wanted:
                            out[wanted[info.name]] = _size_or_error(
                                wanted[info.name], lambda i=info: handle.extractfile(i).read())
        except (OSError, KeyError, zipfile.BadZipFile, tarfile.TarError) as exc:
            for ref, _ in members:
                out.setdefault(ref, ImageError(f"{ref}: cannot read ({exc})"))
        for ref, _ in members:
            out.setdefault(ref, ImageError(f"{ref}: not a file in the archive"))
    return out


def _size_or_error(ref: str, read):
    try:
        data = read() if read is not None else None
    except (OSError, KeyError, AttributeError, zipfile.BadZipFile, tarfile.TarError) as exc:
        return ImageError(f"{ref}: cannot read ({exc})")
    try:
        return image_header(ref, data)[:2]
    except ImageError as exc:
        return exc
