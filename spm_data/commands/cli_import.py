"""``spm-data import``: real datasets (COIL-100, CVL, BOP, any posed-image folder) into shards
(cli.py adds the group to spm-data). The dataset is the first argument, the shards go to --out."""

from __future__ import annotations

import click

from spm_data.commands.cli_support import Group, executor_options, handle_errors, old_spelling, run_with_progress

import_group = Group("import", help="Turn real datasets (COIL-100, CVL, BOP, any posed-image folder) into shards.")

OUT = click.option("--out", default="out_imported", show_default=True, type=click.Path(),
                   help="Folder to write the shards to.")
THRESHOLD = click.option("--threshold", default=10, show_default=True, type=click.IntRange(0, 254),
                         help="Mask = pixels whose brightest channel is above this (the data has no masks).")
CLASS_MAP = click.option("--class-map", "class_map", type=click.Path(), default=None,
                         help="CSV of object id,class name: the class of each object [default: the object's name].")
WORKERS = executor_options("Import processes")
CLASSES = old_spelling("--classes", "class_map", "use --class-map FILE", type=click.Path())


def _finish_import(call):
    from spm_data.formats.importing import import_report

    problems = []

    def run(bar):
        summary, found = call(bar)
        problems.extend(found)
        return summary

    run_with_progress(run, lambda summary: import_report(summary, problems))


@import_group.command("coil100")
@click.argument("path", type=click.Path())
@OUT
@THRESHOLD
@click.option("--elevation", default=0.0, show_default=True, help="Assumed camera elevation, degrees (not published).")
@click.option("--distance", default=1.0, show_default=True, help="Assumed camera distance, metres (not published).")
@click.option("--fov", default=30.0, show_default=True, help="Assumed vertical field of view, degrees.")
@CLASS_MAP
@WORKERS
@CLASSES
@handle_errors
def import_coil100_cmd(path, out, threshold, elevation, distance, fov, class_map, executor):
    """COIL-100 at PATH: the extracted folder, coil-100.zip or coil-100.tar.gz."""
    from spm_data.formats.coil100 import import_coil100

    _finish_import(lambda bar: import_coil100(path, out, elevation=elevation, distance=distance, fov=fov,
                                              classes_csv=class_map, threshold=threshold, progress=bar,
                                              executor=executor))


@import_group.command("folder")
@click.argument("path", type=click.Path())
@click.option("--poses", "poses_csv", type=click.Path(), default=None, help="Pose table [default: PATH/poses.csv].")
@OUT
@THRESHOLD
@click.option("--unit", default="m", show_default=True, type=click.Choice(["m", "cm", "mm"]), help="Translation unit.")
@click.option("--euler", default="XYZ", show_default=True, help="Euler order of rx ry rz columns (scipy notation).")
@click.option("--fov", type=float, default=None, help="Vertical field of view, degrees, if the table has no fx fy cx cy.")
@click.option("--class", "class_name", default="folder", show_default=True, help="Class when the table has none.")
@click.option("--depth-unit", default="mm", show_default=True, type=click.Choice(["m", "cm", "mm"]),
              help="What one step of a uint16 depth image is.")
@WORKERS
@handle_errors
def import_folder_cmd(path, poses_csv, out, threshold, unit, euler, fov, class_name, depth_unit, executor):
    """Images in PATH plus a table of per-image poses (docs/datasets.md)."""
    from spm_data.formats.posed_folder import import_folder

    _finish_import(lambda bar: import_folder(path, out, poses_csv=poses_csv, unit=unit, euler=euler, fov=fov,
                                             class_name=class_name, depth_unit=depth_unit, threshold=threshold,
                                             progress=bar, executor=executor))


@import_group.command("cvl")
@click.argument("path", type=click.Path())
@OUT
@THRESHOLD
@click.option("--unit", default="mm", show_default=True, type=click.Choice(["m", "cm", "mm"]), help="Translation unit.")
@click.option("--fov", type=float, default=None, help="Vertical field of view, degrees, if tables have no fx fy cx cy.")
@WORKERS
@handle_errors
def import_cvl_cmd(path, out, threshold, unit, fov, executor):
    """CVL at PATH in the assumed layout PATH/<object>/poses.csv (docs/datasets.md)."""
    from spm_data.formats.posed_folder import import_cvl

    _finish_import(lambda bar: import_cvl(path, out, unit=unit, fov=fov, threshold=threshold,
                                          progress=bar, executor=executor))


@import_group.command("bop")
@click.argument("path", type=click.Path())
@OUT
@click.option("--split", default="train_pbr", show_default=True, help="BOP split folder.")
@click.option("--crop", type=click.IntRange(min=8), default=None, help="Square crops of this size around each object.")
@CLASS_MAP
@WORKERS
@CLASSES
@handle_errors
def import_bop_cmd(path, out, split, crop, class_map, executor):
    """A BOP dataset split at PATH, one frame per (image, object); masks are BOP's own (mask_visib)."""
    from spm_data.formats.bop import import_bop

    _finish_import(lambda bar: import_bop(path, out, split=split, crop=crop, classes_csv=class_map,
                                          progress=bar, executor=executor))
