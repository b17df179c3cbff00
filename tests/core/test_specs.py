import pytest

from spm_data.errors import SpecError
from spm_data.core.shapes import CLASSES
from spm_data.core.specs import all_spec_paths, load_spec, parse_spec, shard_spec


def test_builtin_specs_cover_the_six_classes_and_load():
    paths = all_spec_paths()
    assert sorted(p.stem for p in paths) == sorted(CLASSES)
    for p in paths:
        spec = load_spec(p)
        assert spec.class_name == p.stem
        assert (spec.image.width, spec.image.height) == (128, 128)
        assert spec.camera.azimuth.step == 5 and spec.camera.elevation.stop == 60


def test_defaults_fill_missing_sections():
    spec = parse_spec('class = "cup"')
    assert spec.mesh.instances == 4 and spec.render.renderer == "blender"
    assert spec.render.blender.engine == "cycles" and spec.render.blender.samples == 16


def test_fingerprint_changes_with_what_changes_pixels():
    a = parse_spec('class = "cup"\nseed = 1')
    b = parse_spec('class = "cup"\nseed = 2')
    c = parse_spec('# a comment\nclass = "cup"\nseed = 1')
    assert a.fingerprint() != b.fingerprint()
    assert a.fingerprint() == c.fingerprint()
    # Declared symmetries go to the BOP export only: the pixels, so the fingerprint, stay.
    files = 'class = "u"\n[mesh]\nsource = "files"\nfiles = ["a.ply"]\n'
    assert parse_spec(files).fingerprint() == parse_spec(files + 'symmetries = ["z"]\n').fingerprint()
    # device = "cpu" is the default: written out or not, the same fingerprint; "auto" is another.
    assert a.fingerprint() == parse_spec('class = "cup"\nseed = 1\n[render.blender]\ndevice = "cpu"').fingerprint()
    assert a.fingerprint() != parse_spec('class = "cup"\nseed = 1\n[render.blender]\ndevice = "auto"').fingerprint()
    # A sampler's keys change the views, so the fingerprint.
    so3 = 'class = "cup"\n[camera]\nsampler = "so3"\nviews = 10\n'
    assert parse_spec(so3).fingerprint() != parse_spec(so3.replace("10", "11")).fingerprint() != a.fingerprint()


@pytest.mark.parametrize("text, message", [
    ('class = "cup"\n[camera]\nazimth = [0, 355, 5]', "camera.azimth: unknown key"),
    ('class = "cup"\ncolour = 3', "colour: unknown key"),
    ('class = "cup"\n[render.blender]\nengin = "cycles"', "render.blender.engin: unknown key"),
    ('class = "cup"\n[image]\nwidth = "128"', "image.width: expected int, got string"),
    ('class = "cup"\n[image]\nwidth = 0', "width and height must be >= 1"),
    ('class = "cup"\n[image]\nfov = 200', "image.fov"),
    ('class = "cup"\n[camera]\nazimuth = [0, 355, 7]', "camera.azimuth: step 7.0 does not divide"),
    ('class = "cup"\n[camera]\ndistances = [0.5, -1]', "camera.distances"),
    ('class = "cup"\n[camera]\nazimuth = [0, 355]', "camera.azimuth: expected [start, stop, step]"),
    ('class = "cup"\n[mesh]\ninstances = 0', "mesh.instances"),
    ('class = "cup"\n[mesh]\nsize = -1', "mesh.size"),
    ('class = "teapot"', "not a built-in class"),
    ('class = "cup"\n[render]\nrenderer = "povray"', "render.renderer"),
    ('class = "cup"\n[render]\nframes_per_shard = true', "render.frames_per_shard: expected int, got boolean"),
    ('seed = 1', "class: missing"),
    ('class = "cup"\n[mesh', "not valid TOML"),
    ('class = "cup"\nmesh = 3', "mesh: expected a table"),
    ('class = "cup"\n[mesh]\nsymmetries = ["z"]', "mesh.symmetries: built-in classes know their own"),
    ('class = "cup"\n[camera]\nsampler = "so3"', "camera.views: sampler 'so3' needs views = N >= 1"),
    ('class = "cup"\n[camera]\nsampler = "so3"\nviews = "ten"', "camera.views: expected int, got string"),
    ('class = "cup"\n[camera]\nsampler = "sphere"\nviews = 3\nroll_range = [10]', "camera.roll_range: expected [low, "
                                                                                  "high]"),
    ('class = "cup"\n[camera]\nroll_range = [0, 10]', "camera.roll_range: only for sampler"),
    ('class = "cup"\n[render.blender]\ndevice = "tpu"', "render.blender.device: expected one of cpu, gpu, auto, got "
                                                        "'tpu'"),
    ('class = "u"\n[mesh]\nsource = "files"\nfiles = ["a.ply"]\nsymmetries = ["q/90"]',
     "mesh.symmetries[0]: symmetry 'q/90': expected an axis x, y or z"),
    ('class = "u"\n[mesh]\nsource = "files"\nfiles = ["a.ply"]\nsymmetries = ["z", "z/7"]',
     "mesh.symmetries[1]: symmetry 'z/7': the turn must be less than 360 degrees and divide it"),
])
def test_bad_specs_name_the_key(text, message):
    with pytest.raises(SpecError) as err:
        parse_spec(text, name="x.toml")
    assert str(err.value).startswith("x.toml: ")
    assert message in str(err.value)
    assert "\n" not in str(err.value)


def test_missing_spec_file(tmp_path):
    with pytest.raises(SpecError, match="spec not found"):
        load_spec(tmp_path / "nope.toml")


def test_the_example_specs_load():
    from pathlib import Path

    from spm_data.core.specs import load_spec

    examples = sorted((Path(__file__).resolve().parents[2] / "examples" / "specs").glob("*.toml"))
    assert examples
    for path in examples:
        spec = load_spec(path)
        assert spec.randomize.enabled and spec.distractors.count == 2 and spec.outputs.coords


def test_a_shards_spec_is_its_text_with_the_runs_seed():
    text = 'class = "cup"\nseed = 7\n[mesh]\ngenerator = "cup"\n'
    spec = shard_spec({"spec": text, "seed": 11})
    assert spec.seed == 11 and spec.class_name == "cup"
    assert spec.fingerprint() == parse_spec(text).replace(seed=11).fingerprint()
    assert shard_spec({"spec": text}).seed == 0   # a shard without the attribute: the default seed
