"""``spm predict`` trusts no input: the region of interest, 16-bit images, bad images
among good ones, and damaged model files (tests build two small models here)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from cli import model_cli
from spm_data.io.images import decode_image
from spm_data.core.poses import intrinsics_from_fov
from spm_model.spm.estimator import SPMEstimator
from spm_model.spm.features import FeatureConfig, image_features
from spm_model.methods.template import TemplatePose
from tests.helpers import sealed_model

SIDE = 96
SPM_CMD = Path(sys.executable).with_name("spm")


def textured(seed, side=SIDE, peak=200):
    """Dots of random grey levels up to ``peak`` on black: plenty of SIFT keypoints."""
    rng = np.random.default_rng(seed)
    img = np.zeros((side, side, 3), np.uint8)
    for _ in range(40):
        colour = tuple(int(v) for v in rng.integers(30, peak, 3))
        centre = tuple(int(v) for v in rng.integers(16, side - 16, 2))
        cv2.circle(img, centre, int(rng.integers(2, 7)), colour, -1)
    return img


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    """{"spm": model.npz, "template": reference-model.npz}: fitted in seconds on 12 synthetic
    images with made-up poses (the poses are meaningless; these tests compare predictions)."""
    root = tmp_path_factory.mktemp("models")
    config = FeatureConfig(ellipse="direct")
    images = [textured(seed) for seed in range(12)]
    X = np.stack([image_features(im, None, config, raw=False)["vector"] for im in images])
    rng = np.random.default_rng(0)
    y = np.column_stack([rng.uniform(-170, 170, (12, 3)), rng.uniform(-0.1, 0.1, (12, 2)), rng.uniform(0.5, 0.8, 12)])
    K = intrinsics_from_fov(35, SIDE, SIDE)
    frames = [{"rgb": im, "mask": im.max(axis=2) > 0, "K": K} for im in images]
    return {"spm": SPMEstimator(features=config).fit(X, y).save(root / "model.npz"),
            "template": TemplatePose().fit(frames, y).save(root / "reference-model.npz")}


def predict(model, *args):
    return CliRunner().invoke(model_cli, ["predict", "--model", str(model), *[str(a) for a in args]])


def refused(r, message):
    """Exit 1, nothing on stdout, stderr exactly ``error: MESSAGE``, no traceback."""
    assert r.exit_code == 1, r.output
    assert r.exception is None or isinstance(r.exception, SystemExit), r.exc_info
    assert r.stdout == "" and "Traceback" not in r.output
    assert r.stderr == f"error: {message}\n", r.stderr


def save(path, array):
    Image.fromarray(array).save(path)
    return path


# ---------------------------------------------------------------- the region of interest

ROI_RULE = "the image is 96x96 pixels: give a box inside it (x, y >= 0, width, height >= 1, x + width <= 96, " \
           "y + height <= 96)"


@pytest.mark.parametrize("kind", ["spm", "template"])
@pytest.mark.parametrize("roi, problem", [
    ("-10,-10,5,5", "starts at a negative x or y"),
    ("10,-1,20,20", "starts at a negative x or y"),
    ("0,0,0,5", "is empty (width and height must be at least 1)"),
    ("10,10,5,-3", "is empty (width and height must be at least 1)"),
    ("500,500,4,4", "lies outside the image"),
    ("90,0,20,20", "reaches outside the image (x + width = 110, y + height = 20)"),
    ("0,0,96,97", "reaches outside the image (x + width = 96, y + height = 97)"),
])
def test_roi_is_checked_against_the_image(models, tmp_path, kind, roi, problem):
    image = save(tmp_path / "a.png", textured(99))
    refused(predict(models[kind], image, "--roi", roi), f"{image}: --roi {roi} {problem}; {ROI_RULE}")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png"]


def test_roi_against_each_image_and_its_syntax(models, tmp_path):
    big, small = save(tmp_path / "big.png", textured(99)), save(tmp_path / "small.png", textured(98, side=64))
    r = predict(models["spm"], big, small, "--roi", "40,0,50,50")
    assert r.exit_code == 1
    assert r.stdout.startswith(f"{big}: rx ") and r.stdout.count("\n") == 1          # the box fits big.png
    assert r.stderr == (f"error: {small}: --roi 40,0,50,50 reaches outside the image (x + width = 90, "
                        "y + height = 50); the image is 64x64 pixels: give a box inside it (x, y >= 0, width, height "
                        ">= 1, "
                        "x + width <= 64, y + height <= 64)\n")
    assert predict(models["spm"], big, "--roi", "0,0,96,96").exit_code == 0           # the whole image is fine
    refused(predict(models["spm"], big, "--roi", "1,2,3"),
            "--roi expects x,y,width,height in whole pixels, got '1,2,3'; e.g. --roi 200,120,240,240")


# ---------------------------------------------------------------- 16-bit images

def test_16_bit_is_scaled_by_a_fixed_factor(tmp_path):
    grey = textured(5, peak=120)[..., 0]      # dim: a per-image stretch would brighten it
    assert grey.max() < 120
    save(tmp_path / "g16.png", grey.astype(np.uint16) * 257)
    assert Image.open(tmp_path / "g16.png").mode == "I;16"
    np.testing.assert_array_equal(decode_image((tmp_path / "g16.png").read_bytes()), np.repeat(grey[..., None], 3, 2))
    cv2.imwrite(str(tmp_path / "g16.tif"), grey.astype(np.uint16) * 257)
    np.testing.assert_array_equal(decode_image((tmp_path / "g16.tif").read_bytes())[..., 0], grey)
    # 16-bit colour: round(v / 257), not Pillow's high byte (200 / 257 -> 1, 200 >> 8 = 0).
    values = np.array([[[0, 200, 128], [65535, 33023, 32896]]], np.uint16)   # RGB
    cv2.imwrite(str(tmp_path / "c16.png"), values[..., ::-1])
    assert decode_image((tmp_path / "c16.png").read_bytes()).tolist() == [[[0, 1, 0], [255, 128, 128]]]


@pytest.mark.parametrize("kind", ["spm", "template"])
def test_8_and_16_bit_copies_give_the_same_pose(models, tmp_path, kind):
    rgb = textured(7, peak=120)
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    files = [save(tmp_path / "rgb8.png", rgb), save(tmp_path / "grey8.png", grey),
             save(tmp_path / "grey16.png", grey.astype(np.uint16) * 257), tmp_path / "rgb16.png"]
    cv2.imwrite(str(files[3]), rgb[..., ::-1].astype(np.uint16) * 257)
    r = predict(models[kind], *files, "--json")
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    assert [o["image"] for o in out] == [str(f) for f in files]
    poses = [o["pose"] for o in out]
    assert poses[0] == poses[3] and poses[1] == poses[2]    # each 8-bit image and its 16-bit copy: identical
    assert all(np.isfinite(list(p.values())).all() for p in poses)


# ---------------------------------------------------------------- bad images among good ones

@pytest.fixture
def mixed_images(tmp_path, monkeypatch):
    """[(path, None or the error line's reason)]: good images around a missing one, a text file,
    a truncated PNG and two over Pillow's decompression-bomb limit (lowered here to 20,000 pixels:
    its warning range, 20,000 to 40,000, and its error range above)."""
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 20000)
    good = save(tmp_path / "good.png", textured(11))
    data = good.read_bytes()
    (tmp_path / "truncated.png").write_bytes(data[: len(data) // 2])
    (tmp_path / "notes.png").write_text("not an image\n")
    save(tmp_path / "warn.png", np.zeros((150, 150, 3), np.uint8))
    save(tmp_path / "bomb.png", np.zeros((250, 250, 3), np.uint8))
    limit = "is over the decompression-bomb limit of 20,000 pixels (Pillow's PIL.Image.MAX_IMAGE_PIXELS); " \
            "downscale the image"
    return [(good, None), (tmp_path / "missing.png", "no such file"),
            (tmp_path / "notes.png", "not a readable image (unknown format, or a truncated header)"),
            (save(tmp_path / "good2.png", textured(12)), None),
            (tmp_path / "truncated.png", "not a readable image (truncated or corrupt: image file is truncated)"),
            (tmp_path / "warn.png", f"22,500 pixels {limit}"), (tmp_path / "bomb.png", f"62,500 pixels {limit}"),
            (tmp_path, "is a folder, not an image file")]


@pytest.mark.parametrize("kind", ["spm", "template"])
def test_bad_images_are_reported_and_the_rest_predicted(models, mixed_images, kind):
    paths = [p for p, _ in mixed_images]
    errors = "".join(f"error: {p}: {why}\n" for p, why in mixed_images if why)
    r = predict(models[kind], *paths)
    assert r.exit_code == 1 and "Traceback" not in r.output
    lines = r.stdout.splitlines()
    assert [line.split(": rx ")[0] for line in lines] == [str(p) for p, why in mixed_images if not why]
    assert r.stderr == errors
    # --json: every image in order, failed ones with their reason; stderr the same lines.
    r = predict(models[kind], *paths, "--json")
    assert r.exit_code == 1 and r.stderr == errors
    out = json.loads(r.stdout)
    assert [o["image"] for o in out] == [str(p) for p in paths]
    for o, (_, why) in zip(out, mixed_images):
        assert o.get("error") == why and ("pose" in o) == (why is None)
    # A good image alone: exit 0, nothing on stderr.
    r = predict(models[kind], paths[0])
    assert r.exit_code == 0 and r.stderr == "" and r.stdout.startswith(f"{paths[0]}: rx ")


def test_bad_images_as_a_process(models, tmp_path):
    """The installed command: results on stdout, one error line per bad image on stderr, exit 1."""
    good = save(tmp_path / "good.png", textured(11))
    (tmp_path / "truncated.png").write_bytes(good.read_bytes()[:200])
    proc = subprocess.run([str(SPM_CMD), "predict", "--model", str(models["spm"]), str(good),
                           str(tmp_path / "truncated.png"), str(tmp_path / "none.png")],
                          capture_output=True, text=True, env={**os.environ, "PYOPENGL_PLATFORM": "egl"}, timeout=300)
    assert proc.returncode == 1
    assert proc.stdout.startswith(f"{good}: rx ") and proc.stdout.count("\n") == 1
    assert proc.stderr == (f"error: {tmp_path / 'truncated.png'}: not a readable image (truncated or corrupt: "
                           f"image file is truncated)\nerror: {tmp_path / 'none.png'}: no such file\n")


# ---------------------------------------------------------------- --mask

def test_mask_problems(models, tmp_path):
    image = save(tmp_path / "a.png", textured(3))
    save(tmp_path / "empty.png", np.zeros((SIDE, SIDE), np.uint8))
    save(tmp_path / "small.png", np.full((40, 50), 255, np.uint8))
    model = models["template"]
    refused(predict(model, image, "--mask", tmp_path / "none.png"), f"--mask {tmp_path / 'none.png'}: no such file")
    refused(predict(model, image, "--mask", tmp_path / "empty.png"),
            f"--mask {tmp_path / 'empty.png'}: no object pixel (every value is 0); give a mask with the object "
            "non-zero")
    refused(predict(model, image, "--mask", tmp_path / "small.png"),
            f"{image}: --mask {tmp_path / 'small.png'} is 50x40 pixels, the image 96x96; give a mask of the "
            "image's size")


# ---------------------------------------------------------------- damaged and foreign model files

RETRAIN = "retrain it with spm train"
FOREIGN = "give the model.npz or reference-model.npz that spm train wrote, or retrain with spm train"


def damaged_models(models, root):
    """[(path, exact message)] of model files that must be refused."""
    out = []
    for kind in ("spm", "template"):
        data = Path(models[kind]).read_bytes()
        path = root / f"truncated-{Path(models[kind]).name}"
        path.write_bytes(data[: len(data) // 2])
        out.append((path, f"{path}: damaged spm model file (truncated or corrupt: BadZipFile: File is not a zip file); "
                          f"{RETRAIN}"))
    data = bytearray(Path(models["spm"]).read_bytes())
    at = data.index(b"centres.npy") + 200     # inside the centres array's bytes
    data[at] ^= 0xFF
    (root / "flipped.npz").write_bytes(bytes(data))
    out.append((root / "flipped.npz", f"{root / 'flipped.npz'}: damaged spm model file (truncated or corrupt: "
                                      f"BadZipFile: Bad CRC-32 for file 'centres.npy'); {RETRAIN}"))
    (root / "empty.npz").write_bytes(b"")
    out.append((root / "empty.npz", f"{root / 'empty.npz'}: damaged spm model file (an empty file); {RETRAIN}"))
    (root / "photo.npz").write_bytes((root / "a.png").read_bytes())
    out.append((root / "photo.npz", f"{root / 'photo.npz'}: not an spm model file (not an .npz archive); {FOREIGN}"))
    np.savez(root / "other.npz", weights=np.zeros(3))
    out.append((root / "other.npz", f"{root / 'other.npz'}: not an spm model file (an .npz archive without spm's "
                                    f"header); {FOREIGN}"))
    with open(root / "array.npz", "wb") as fh:
        np.save(fh, np.zeros(3))
    out.append((root / "array.npz", f"{root / 'array.npz'}: not an spm model file (a single numpy array, not an "
                                    f".npz archive); {FOREIGN}"))
    sealed_model(root / "kind.npz", {"format": 2, "kind": "forest", "params": {}}, {})
    out.append((root / "kind.npz", f"{root / 'kind.npz'}: not an spm model file (kind 'forest', expected one of "
                                   "['cnn', 'spm', 'template']); give the model.npz, reference-model.npz or "
                                   "cnn-model.npz that spm train wrote"))
    sealed_model(root / "hollow.npz", {"format": 2, "kind": "spm", "params": {}}, {})
    out.append((root / "hollow.npz", f"{root / 'hollow.npz'}: damaged spm model file (no 'features' in it); {RETRAIN}"))
    arrays = dict(np.load(models["template"]))
    header, seal = json.loads(str(arrays.pop("header"))), arrays.pop("seal")
    arrays["poses"] = arrays["poses"][:3]
    np.savez(root / "unsealed.npz", header=np.array(json.dumps(header)), seal=seal, **arrays)   # a valid zip
    out.append((root / "unsealed.npz", f"{root / 'unsealed.npz'}: damaged spm model file (what it holds differs "
                                       f"from its SHA-256 seal); {RETRAIN}"))
    np.savez(root / "format1.npz", header=np.array(json.dumps({**header, "format": 1})), **arrays)
    out.append((root / "format1.npz", f"{root / 'format1.npz'}: model format 1 has no SHA-256 seal, so it cannot "
                                      f"be verified; {RETRAIN} (spm 0.1.0 writes format 2)"))
    sealed_model(root / "cut.npz", header, arrays)
    out.append((root / "cut.npz", f"{root / 'cut.npz'}: damaged spm model file (templates of different lengths "
                                  f"(codes (12, 11), poses (3, 6), geometry (12, 7), distance (12,))); {RETRAIN}"))
    out.append((root / "none.npz", f"model file not found: {root / 'none.npz'}; train one with spm train"))
    return out


def test_damaged_model_files_are_one_line(models, tmp_path):
    image = save(tmp_path / "a.png", textured(4))
    cases = damaged_models(models, tmp_path)
    before = sorted(p.name for p in tmp_path.iterdir())
    for path, message in cases:
        refused(predict(path, image), message)
        refused(predict(path, image, "--json"), message)
    assert sorted(p.name for p in tmp_path.iterdir()) == before    # predict wrote nothing


def test_what_is_not_a_regular_file_or_too_big_is_refused_before_reading(models, tmp_path, monkeypatch):
    """/dev/zero (read 24 GB once) and a FIFO named like an image (hung once) are refused
    without reading or waiting; a file over MAX_IMAGE_BYTES before it is read."""
    from spm_data.io import images

    good = save(tmp_path / "good.png", textured(11))
    fifo = tmp_path / "x.png"
    os.mkfifo(fifo)
    big = save(tmp_path / "big.png", textured(12))
    monkeypatch.setattr(images, "MAX_IMAGE_BYTES", big.stat().st_size - 1)
    monkeypatch.setattr(images.read_image_file, "__defaults__", (big.stat().st_size - 1,))
    r = predict(models["spm"], "/dev/zero", fifo, big, good)
    assert r.exit_code == 1 and r.stdout.startswith(f"{good}: rx ") and r.stdout.count("\n") == 1
    assert r.stderr == (f"error: /dev/zero: is a character device, not a regular file; give an image file\n"
                        f"error: {fifo}: is a FIFO, not a regular file; give an image file\n"
                        f"error: {big}: {big.stat().st_size:,} bytes is over the image file limit of "
                        f"{big.stat().st_size - 1:,} bytes (spm_data.io.images.MAX_IMAGE_BYTES); downscale or "
                        "recompress the image\n")
    refused(predict(models["spm"], good, "--mask", fifo),
            f"--mask {fifo}: is a FIFO, not a regular file; give an image file")


@pytest.mark.parametrize("command", ["predict", "evaluate"])
def test_a_model_that_is_a_fifo_device_folder_or_too_big_is_refused_before_reading(models, tmp_path, monkeypatch,
                                                                                   command):
    """--model naming a FIFO hung predict and evaluate; now it, /dev/zero, a folder and a file over
    MAX_MODEL_BYTES are one line each, without reading or waiting."""
    from spm_model.base import model_files

    image = save(tmp_path / "a.png", textured(4))
    fifo = tmp_path / "model.npz"
    os.mkfifo(fifo)
    (tmp_path / "folder.npz").mkdir()
    size = Path(models["spm"]).stat().st_size
    monkeypatch.setattr(model_files, "MAX_MODEL_BYTES", size - 1)
    foreign = "give the model.npz or reference-model.npz that spm train wrote, or retrain with spm train"
    cases = [(fifo, f"{fifo}: is a FIFO, not a model file; {foreign}"),
             ("/dev/zero", f"/dev/zero: is a character device, not a model file; {foreign}"),
             (tmp_path / "folder.npz", f"{tmp_path / 'folder.npz'}: is a folder, not a model file; {foreign}"),
             (models["spm"], f"{models['spm']}: {size:,} bytes is over the limit of {size - 1:,} bytes "
                             f"(spm_model.base.model_files.MAX_MODEL_BYTES), not a model file; {foreign}")]
    for model, message in cases:
        args = ["predict", "--model", str(model), str(image)] if command == "predict" else \
            ["evaluate", str(tmp_path / "no-shards"), "--model", str(model)]
        refused(CliRunner().invoke(model_cli, args), message)


def test_a_file_name_with_a_newline_stays_on_its_line(models, tmp_path):
    """A name with a newline split predict's output line (a forged second result); now control
    characters print as escapes on stdout and stderr, and --json keeps the exact name."""
    good = save(tmp_path / "a\nb: rx 0.0.png", textured(4))
    missing = tmp_path / "c\rd.png"
    r = predict(models["spm"], good, missing)
    assert r.exit_code == 1 and r.stdout.count("\n") == 1, r.stdout
    assert r.stdout.startswith(f"{tmp_path}/a\\nb: rx 0.0.png: rx ")
    assert r.stderr == f"error: {tmp_path}/c\\rd.png: no such file\n"
    r = predict(models["spm"], good, "--json")
    assert r.exit_code == 0 and json.loads(r.stdout)[0]["image"] == str(good)
