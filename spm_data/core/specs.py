"""Render specs: one TOML file per class (render_specs/), loaded once into frozen dataclasses.

Every key is checked: an unknown key, a wrong type or a bad value raises
SpecError naming the file and the key (``cup.toml: camera.azimth: unknown key``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from spm_data.errors import MeshError, SpecError
from spm_data.core.shapes import CLASSES
from spm_data.core.symmetries import declared_symmetries, parse_symmetry
from spm_data.core.paths import SAMPLER_KEYS, AngleRange, CameraGrid, camera_path
from spm_data.core.distractors import DistractorSpec, validate_distractors
from spm_data.core.randomize import RandomizeSpec, validate_randomize
from spm_data.render import RENDERERS

BACKGROUNDS = ("black", "color", "images")


@dataclass(frozen=True)
class MeshSpec:
    source: str = "procedural"      # "procedural" | "files"
    generator: str = ""             # procedural class; defaults to the spec's class
    instances: int = 4              # procedural instances
    files: tuple[str, ...] = ()     # globs relative to the spec file, for source = "files"
    size: float = 0.25              # longest bounding-box side, metres
    texture: str = "auto"           # "auto" (keep a file's own image texture) | "procedural"
    symmetries: tuple[str, ...] = ()  # for files: "z" (every turn about z), "x/180" (n-fold turns)
    up: str = "z"                   # for files: the axis that is up in them, "z" or "y" (glTF: always y)


@dataclass(frozen=True)
class ImageSpec:
    width: int = 128
    height: int = 128
    fov: float = 35.0               # vertical field of view, degrees


@dataclass(frozen=True)
class LightingSpec:
    ambient: float = 0.3            # 0..1 of white
    lights: int = 3                 # directional lights that move with the camera
    strength: float = 1.6           # per light (pyrender lux-like; Blender sun strength)


@dataclass(frozen=True)
class BackgroundSpec:
    kind: str = "black"             # "black" | "color" | "images"
    color: tuple[float, float, float] = (0.0, 0.0, 0.0)  # RGB 0..1, for kind = "color"
    folder: str = ""                # images, for kind = "images" (relative to the spec file)


# [render]: the renderer's name, shard size, and one settings table per registered renderer that has
# settings ([render.blender], ...), each the backend's own dataclass (spm_data/render/__init__.py).
RenderSettings = dataclasses.make_dataclass(
    "RenderSettings",
    [("renderer", "str", field(default="blender")), ("frames_per_shard", "int", field(default=256)),
     *[(name, b.settings, field(default=b.settings())) for name, b in RENDERERS.items() if b.settings]],
    frozen=True)
RenderSettings.__module__ = __name__  # pickled with the spec to worker processes


@dataclass(frozen=True)
class OutputsSpec:
    """Opt-in per-pixel outputs besides rgb, depth and mask (docs/shard-format.md)."""

    normals: bool = False           # camera-frame unit normals
    instances: bool = False         # per-pixel instance id: 0 none, 1 the target, 2.. the distractors
    coords: bool = False            # object-frame coordinates of each visible target pixel (NOCS-style)


# Tables whose defaults change nothing: a spec without them keeps the fingerprint it had before they existed.
OPTIONAL_TABLES = {"randomize": RandomizeSpec(), "distractors": DistractorSpec(), "outputs": OutputsSpec()}


@dataclass(frozen=True)
class RenderSpec:
    class_name: str
    seed: int = 0
    mesh: MeshSpec = MeshSpec()
    camera: CameraGrid = CameraGrid()
    image: ImageSpec = ImageSpec()
    lighting: LightingSpec = LightingSpec()
    background: BackgroundSpec = BackgroundSpec()
    render: RenderSettings = RenderSettings()
    randomize: RandomizeSpec = RandomizeSpec()
    distractors: DistractorSpec = DistractorSpec()
    outputs: OutputsSpec = OutputsSpec()
    base_dir: str = field(default=".", compare=False)  # where relative paths in the spec start
    text: str = field(default="", compare=False, repr=False)  # the TOML as written

    def replace(self, **changes) -> "RenderSpec":
        return dataclasses.replace(self, **changes)

    def fingerprint(self) -> str:
        """sha256 of everything that changes the rendered arrays."""
        payload = dataclasses.asdict(self)
        payload.pop("text"), payload.pop("base_dir")
        payload["mesh"].pop("symmetries")  # metadata for the BOP export: the pixels do not change
        if self.mesh.up == "z":  # the default: a spec without the key keeps its fingerprint
            payload["mesh"].pop("up")
        for name, backend in RENDERERS.items():  # settings added later: at their default, the old fingerprint
            for key, default in getattr(backend.settings, "FINGERPRINT_SKIPS", {}).items():
                if getattr(getattr(self.render, name), key) == default:
                    payload["render"][name].pop(key)
        for key, default in OPTIONAL_TABLES.items():
            if getattr(self, key) == default:
                payload.pop(key)
        if self.camera.sampler == "grid":  # keys the grid does not use: a grid spec's fingerprint stays as it was
            for key in SAMPLER_KEYS:
                payload["camera"].pop(key)
        return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()


# --------------------------------------------------------------------------- generic checked loading

def _type_name(value) -> str:
    return {bool: "boolean", int: "integer", float: "float", str: "string", list: "array",
            dict: "table"}.get(type(value), type(value).__name__)


def _convert(value, annotation: str, key: str):
    if annotation == "bool":
        if isinstance(value, bool):
            return value
    elif annotation == "int":
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif annotation == "float":
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            if value != value or value in (float("inf"), float("-inf")):
                raise SpecError(f"{key}: expected a finite number, got {value}")
            return float(value)
    elif annotation == "str":
        if isinstance(value, str):
            return value
    elif annotation.startswith("tuple[float"):
        if isinstance(value, list):
            items = tuple(_convert(v, "float", f"{key}[{i}]") for i, v in enumerate(value))
            if annotation.count("float") == 3 and len(items) != 3:
                raise SpecError(f"{key}: expected 3 numbers, got {len(items)}")
            return items
    elif annotation.startswith("tuple[str"):
        if isinstance(value, list):
            return tuple(_convert(v, "str", f"{key}[{i}]") for i, v in enumerate(value))
    elif annotation == "AngleRange":
        if isinstance(value, list) and len(value) == 3:
            return AngleRange(*(_convert(v, "float", f"{key}[{i}]") for i, v in enumerate(value)))
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return AngleRange(float(value), float(value), 1.0)
        raise SpecError(f"{key}: expected [start, stop, step] in degrees or one number, got {value!r}")
    expected = {"tuple[float, ...]": "array of numbers", "tuple[str, ...]": "array of strings",
                "tuple[float, float, float]": "array of 3 numbers"}.get(annotation, annotation)
    raise SpecError(f"{key}: expected {expected}, got {_type_name(value)} {value!r}")


def _build(cls, table: dict, prefix: str):
    if not isinstance(table, dict):
        raise SpecError(f"{prefix.rstrip('.')}: expected a table, got {_type_name(table)}")
    known = {f.name: f for f in dataclasses.fields(cls) if f.name not in ("text", "base_dir", "class_name")}
    values = {}
    for key, value in table.items():
        if key not in known:
            raise SpecError(f"{prefix}{key}: unknown key (expected one of: {', '.join(sorted(known))})")
        kind = known[key].type
        if dataclasses.is_dataclass(kind):  # a renderer's settings table, e.g. [render.blender]
            values[key] = _build(kind, value, f"{prefix}{key}.")
        else:
            values[key] = _convert(value, kind if isinstance(kind, str) else kind.__name__, prefix + key)
    return cls(**values)


_SECTIONS = {"mesh": MeshSpec, "camera": CameraGrid, "image": ImageSpec, "lighting": LightingSpec,
             "background": BackgroundSpec, "render": RenderSettings, "randomize": RandomizeSpec,
             "distractors": DistractorSpec, "outputs": OutputsSpec}


def shard_spec(attrs: dict, name: str = "<spec>", base_dir: str = ".") -> RenderSpec:
    """The spec a synthetic shard was rendered from, rebuilt from its attributes (its spec text and
    the seed the run used, which --seed may have changed)."""
    return parse_spec(str(attrs["spec"]), name, base_dir).replace(seed=int(attrs.get("seed", 0)))


def parse_spec(text: str, name: str = "<spec>", base_dir: str = ".") -> RenderSpec:
    """Parse and validate TOML ``text``; ``name`` prefixes every error message."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"{name}: not valid TOML ({exc})") from None
    try:
        return _validate(_parse(data, text, base_dir))
    except SpecError as exc:
        raise SpecError(f"{name}: {exc}") from None


def _parse(data: dict, text: str, base_dir: str) -> RenderSpec:
    allowed = {"class", "seed", *_SECTIONS}
    for key in data:
        if key not in allowed:
            raise SpecError(f"{key}: unknown key (expected one of: {', '.join(sorted(allowed))})")
    if "class" not in data:
        raise SpecError("class: missing; name the class, e.g. class = \"cup\"")
    class_name = _convert(data["class"], "str", "class")
    seed = _convert(data.get("seed", 0), "int", "seed")
    sections = {key: _build(cls, data.get(key, {}), f"{key}.") for key, cls in _SECTIONS.items()}
    return RenderSpec(class_name=class_name, seed=seed, base_dir=base_dir, text=text, **sections)


def _check(ok: bool, message: str) -> None:
    if not ok:
        raise SpecError(message)


MAX_CLASS_BYTES = 200  # CLASS-00000.h5 inside .NAME.partial stays under the usual 255-byte file-name limit
MAX_SEED = 2**63 - 1


def _file_name_ok(name: str) -> bool:
    """Whether ``name`` can start a visible file name on any common file system."""
    return (name.strip() != "" and not name.startswith((".", " ")) and len(name.encode("utf-8")) <= MAX_CLASS_BYTES
            and not any(c in name for c in "/\\") and all(ord(c) >= 32 and ord(c) != 127 for c in name))


def validate_spec(spec: RenderSpec) -> RenderSpec:
    """``spec`` once more through every check (after a command-line override); SpecError."""
    return _validate(spec)


def class_name_problem(name: str) -> str | None:
    """Why ``name`` cannot be a class name (it names shard files: CLASS-00000.h5), or None. The
    one rule for specs, importers' class maps and merge's --rename."""
    if _file_name_ok(name):
        return None
    return (f"{name!r} cannot name a shard file (CLASS-00000.h5): expected a non-empty name that does not start "
            f"with '.' or a space, without '/', '\\' or control characters, at most {MAX_CLASS_BYTES} bytes")


def _validate(spec: RenderSpec) -> RenderSpec:
    problem = class_name_problem(spec.class_name)
    _check(problem is None, f"class: {problem}")
    _check(0 <= spec.seed <= MAX_SEED, f"seed: expected an integer in [0, {MAX_SEED}], got {spec.seed}")
    m = spec.mesh
    _check(m.source in ("procedural", "files"), f"mesh.source: expected 'procedural' or 'files', got {m.source!r}")
    if m.source == "procedural":
        gen = m.generator or spec.class_name
        _check(gen in CLASSES, f"mesh.generator: {gen!r} is not a built-in class ({', '.join(CLASSES)}); "
                               "set mesh.source = \"files\" for your own meshes")
        _check(m.instances >= 1, f"mesh.instances: expected an integer >= 1, got {m.instances}")
    else:
        _check(len(m.files) > 0, "mesh.files: give at least one path or glob when mesh.source = \"files\"")
    _check(m.source == "files" or not m.symmetries,
           "mesh.symmetries: built-in classes know their own symmetries; declare them only for mesh files")
    for i, entry in enumerate(m.symmetries):
        try:
            parse_symmetry(entry)
        except MeshError as exc:
            raise SpecError(f"mesh.symmetries[{i}]: {exc}") from None
    try:
        declared_symmetries(m.symmetries)
    except MeshError as exc:
        raise SpecError(f"mesh.symmetries: {exc}") from None
    _check(m.size > 0, f"mesh.size: expected metres > 0, got {m.size}")
    _check(m.texture in ("auto", "procedural"), f"mesh.texture: expected 'auto' or 'procedural', got {m.texture!r}")
    _check(m.up in ("y", "z"), f"mesh.up: expected \"z\" or \"y\" (the axis up in the mesh files), got {m.up!r}")
    _check(m.source == "files" or m.up == "z", "mesh.up: only for mesh files; built-in classes stand on +z")
    im = spec.image
    _check(im.width >= 1 and im.height >= 1, f"image: width and height must be >= 1 pixel, got {im.width}x{im.height}")
    _check(im.width <= 8192 and im.height <= 8192, f"image: at most 8192 pixels a side, got {im.width}x{im.height}")
    _check(0 < im.fov < 180, f"image.fov: expected degrees in (0, 180), got {im.fov}")
    camera_path(spec.camera)  # raises SpecError for steps, ranges, distances
    li = spec.lighting
    _check(0 <= li.ambient <= 1, f"lighting.ambient: expected 0..1, got {li.ambient}")
    _check(0 <= li.lights <= 8, f"lighting.lights: expected 0..8, got {li.lights}")
    _check(li.strength >= 0, f"lighting.strength: expected >= 0, got {li.strength}")
    bg = spec.background
    _check(bg.kind in BACKGROUNDS, f"background.kind: expected one of {', '.join(BACKGROUNDS)}, got {bg.kind!r}")
    _check(all(0 <= c <= 1 for c in bg.color), f"background.color: expected 3 numbers in 0..1, got {list(bg.color)}")
    _check(bg.kind != "images" or bg.folder != "", "background.folder: required when background.kind = \"images\"")
    r = spec.render
    _check(r.renderer in RENDERERS, f"render.renderer: expected one of {', '.join(RENDERERS)}, got {r.renderer!r}")
    _check(r.frames_per_shard >= 1, f"render.frames_per_shard: expected an integer >= 1, got {r.frames_per_shard}")
    validate_randomize(spec.randomize, bg.folder)
    validate_distractors(spec.distractors, spec.base_dir)
    for backend in RENDERERS.values():  # each renderer checks its own settings, and what it cannot draw
        if backend.check:
            backend.check(spec)
    return spec


def load_spec(path) -> RenderSpec:
    """Load ``path`` (a TOML render spec)."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise SpecError(f"spec not found: {path}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SpecError(f"{path}: cannot read spec ({exc})") from None
    return parse_spec(text, name=str(path), base_dir=str(path.parent.resolve()))


def builtin_specs_dir() -> Path:
    """render_specs/ next to the package (a source checkout or editable install)."""
    return Path(__file__).resolve().parents[2] / "render_specs"


def find_spec(class_name: str, specs_dir=None) -> Path:
    """The spec file for ``class_name`` in ``specs_dir`` (default: the built-in folder)."""
    folder = Path(specs_dir) if specs_dir else builtin_specs_dir()
    path = folder / f"{class_name}.toml"
    if not path.is_file():
        available = sorted(p.stem for p in folder.glob("*.toml")) if folder.is_dir() else []
        raise SpecError(f"no spec for class {class_name!r} in {folder} "
                        f"(available: {', '.join(available) or 'none'})")
    return path


def all_spec_paths(specs_dir=None) -> list[Path]:
    folder = Path(specs_dir) if specs_dir else builtin_specs_dir()
    paths = sorted(folder.glob("*.toml"))
    if not paths:
        raise SpecError(f"no *.toml specs in {folder}")
    return paths
