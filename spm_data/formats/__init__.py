"""Other datasets' formats, in and out: COIL-100 and COIL-20 turntables, CVL and posed folders,
transforms.json captures (instant-ngp, nerfstudio), BOP (with PLY models and COCO ground truth).

The importers, one registration each: :data:`IMPORTERS` maps ``spm-data import NAME`` to the
function that imports it and the options it takes. The command line
(spm_cli/importers.py builds one command per entry), its help and the layers test
read this one table.

To add an importer ``xyz``: write ``spm_data/formats/xyz.py`` whose ``import_xyz(path, out_dir,
*, progress, executor, **options)`` turns the dataset into FrameRecords
(spm_data/formats/importing.py) and returns ``import_records``' summary and the problems found
while planning; then one entry below, its options as :class:`Option` values. This module imports
nothing but dataclasses: the importer's module is imported when its command runs.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Option:
    """One command-line option of an importer: ``--flag`` fills the keyword ``name`` of its
    function. ``kind``: "float", "int", "str", "path", "flag" (on/off) or a tuple of choices;
    ``low``/``high``: the accepted range of a number (inclusive; None: open)."""

    flag: str
    name: str
    kind: object
    default: object = None
    help: str = ""
    low: float | None = None
    high: float | None = None


@dataclass(frozen=True)
class Importer:
    """``module``.``function``(path, out_dir, *, progress, executor, **options) ->
    (RunSummary, problems); ``help``: the command's help, its first line says what PATH is;
    ``old``: ((flag, name, advice), ...) spellings kept for one release."""

    module: str
    function: str
    help: str
    options: tuple = ()
    old: tuple = ()


THRESHOLD = Option("--threshold", "threshold", "int", 10, "Mask = pixels whose brightest channel is above this "
                   "(the data has no masks).", 0, 254)
CLASS_MAP = Option("--class-map", "classes_csv", "path", None,
                   "CSV of object id,class name: the class of each object [default: the object's name].")
OLD_CLASSES = (("--classes", "classes_csv", "use --class-map FILE"),)
UNITS = ("m", "cm", "mm")


def _turntable_options(distance: float) -> tuple:
    return (THRESHOLD,
            Option("--elevation", "elevation", "float", 0.0, "Assumed camera elevation, degrees (not published)."),
            Option("--distance", "distance", "float", distance, "Assumed camera distance, metres (not published)."),
            Option("--fov", "fov", "float", 30.0, "Assumed vertical field of view, degrees (K from each image's "
                                                  "own size)."),
            CLASS_MAP)


IMPORTERS: dict[str, Importer] = {
    "coil100": Importer("spm_data.formats.coil100", "import_coil100",
                        "COIL-100 at PATH: the extracted folder, coil-100.zip or coil-100.tar.gz "
                        "(obj{K}__{ANGLE}.png, any size, colour or grey).",
                        _turntable_options(1.0), OLD_CLASSES),
    "coil20": Importer("spm_data.formats.coil100", "import_coil20",
                       "COIL-20 at PATH: the extracted folder or zip (obj{K}__{VIEW}.png, views 0-71 five degrees "
                       "apart, any size, grey or colour).",
                       _turntable_options(1.0)),
    "folder": Importer("spm_data.formats.posed_folder", "import_folder",
                       "Images in PATH plus a table of per-image poses (docs/datasets.md).",
                       (Option("--poses", "poses_csv", "path", None, "Pose table [default: PATH/poses.csv]."),
                        THRESHOLD,
                        Option("--unit", "unit", UNITS, "m", "Translation unit (m, the toolkit's own)."),
                        Option("--euler", "euler", "str", "XYZ", "Euler order of rx ry rz columns (scipy notation)."),
                        Option("--fov", "fov", "float", None, "Vertical field of view, degrees, if the table has no "
                                                              "fx fy cx cy."),
                        Option("--class", "class_name", "str", "folder", "Class when the table has none."),
                        Option("--depth-unit", "depth_unit", UNITS, "mm", "What one step of a uint16 depth image "
                                                                          "is."),
                        Option("--mask", "mask", ("none", "sphere", "grabcut"), None,
                               "Make every frame's mask (none, sphere, grabcut: as import nerf's) [default: the mask "
                               "column, else the threshold]."),
                        Option("--radius", "radius", "float", None, "The sphere of --mask sphere/grabcut: the "
                                                                    "object's radius around its origin, in --unit."))),
    "cvl": Importer("spm_data.formats.posed_folder", "import_cvl",
                    "CVL at PATH in the assumed layout PATH/<object>/poses.csv (docs/datasets.md).",
                    (THRESHOLD,
                     Option("--unit", "unit", UNITS, "mm", "Translation unit (mm: the assumed CVL layout's, "
                                                           "docs/datasets.md; import folder's is m)."),
                     Option("--fov", "fov", "float", None, "Vertical field of view, degrees, if tables have no "
                                                           "fx fy cx cy."))),
    "bop": Importer("spm_data.formats.bop.read", "import_bop",
                    "A BOP dataset split at PATH, one frame per (image, object); masks are BOP's own (mask_visib).",
                    (Option("--split", "split", "str", "train_pbr", "BOP split folder."),
                     Option("--crop", "crop", "int", None, "Square crops of this size around each object.", 8),
                     CLASS_MAP),
                    OLD_CLASSES),
    "nerf": Importer("spm_data.formats.nerf", "import_nerf",
                     "A posed capture at PATH: a folder with transforms.json (or transforms_train/_val/_test.json), "
                     "as instant-ngp and nerfstudio write it (COLMAP, Polycam, Record3D exports), or that file.",
                     (Option("--class", "class_name", "str", None, "Class of the object [default: the folder's name]."),
                      Option("--scale", "scale", "float", None, "Metres per unit of the capture's world frame "
                                                                "(> 0) [default: 1, with a warning]."),
                      Option("--center", "center", "str", "0,0,0", "The object frame's origin, x,y,z in the "
                                                                 "capture's world units."),
                      Option("--mask-dir", "mask_dir", "path", None, "Masks named as the images (any image suffix), "
                                                                    "for frames without alpha or mask_path."),
                      Option("--depth-unit", "depth_unit", UNITS, "mm", "What one step of a uint16 depth image "
                                                                        "(depth_file_path) is."),
                      Option("--mask", "mask", ("none", "sphere", "grabcut"), None,
                             "Make every frame's mask (captures without masks): none = the whole frame, sphere = "
                             "the projection of a sphere of --radius around --center, grabcut = OpenCV GrabCut "
                             "seeded by it [default: mask_path, --mask-dir or the alpha channel]."),
                      Option("--radius", "radius", "float", None, "The sphere of --mask sphere/grabcut: the "
                                                                  "object's radius around --center, world units."),
                      Option("--max-side", "max_side", "int", None, "Downscale frames whose longer side is over "
                             "this many pixels to it, K with them [default: keep the size].", 16),
                      Option("--strict", "strict", "flag", False, "Refuse a capture with missing or unreadable "
                                                                  "images [default: skip those frames, listed]."))),
}


def importer_names() -> tuple[str, ...]:
    """The registered importer names, in registration order."""
    return tuple(IMPORTERS)
