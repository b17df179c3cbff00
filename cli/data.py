"""``spm-data``: make, import, check and export labelled 6-DoF pose datasets (HDF5 shards)."""

from __future__ import annotations

import sys

import click

from cli.common import ALLOW_PARTIAL, Progress, executor_options, handle_errors, run_with_progress


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="spm")
def data_cli():
    """spm-data: make labelled 6-DoF pose datasets (HDF5 shards)."""


@data_cli.command("render")
@click.option("--class", "classes", multiple=True, help="Class to render (its spec is render_specs/CLASS.toml). Repeatable.")
@click.option("--all", "all_classes", is_flag=True, help="Render every spec in the specs folder.")
@click.option("--spec", "spec_files", multiple=True, type=click.Path(), help="A spec file to render. Repeatable.")
@click.option("--specs-dir", type=click.Path(), default=None, help="Where --class/--all look for specs.")
@click.option("--out", default="out", show_default=True, type=click.Path(), help="Output folder.")
@click.option("--workers", default=1, show_default=True, type=click.IntRange(min=1), help="Worker processes.")
@click.option("--renderer", type=click.Choice(["pyrender", "blender"]), default=None, help="Override the spec's renderer.")
@click.option("--seed", type=click.IntRange(min=0), default=None, help="Override the spec's seed.")
@click.option("--limit", type=click.IntRange(min=1), default=None, help="At most N frames per class, spread over views.")
@click.option("--recycle-after", default=16, show_default=True, type=click.IntRange(min=0),
              help="Replace each worker process after this many shards (0: never); bounds renderer leaks.")
@executor_options
@handle_errors
def render_cmd(classes, all_classes, spec_files, specs_dir, out, renderer, seed, limit, executor):
    """Render classes over their camera paths into shards in --out (resumes)."""
    from spm_data.commands.render_jobs import load_run_specs, render_dataset

    specs = load_run_specs(classes, all_classes, spec_files, specs_dir, renderer=renderer, seed=seed)
    run_with_progress(lambda bar: render_dataset(specs, out, limit=limit, progress=bar, executor=executor))


@data_cli.command("occlude")
@click.option("--in", "in_dir", default="out", show_default=True, type=click.Path(), help="Folder of shards to read.")
@click.option("--out", "out_dir", default="out_occluded", show_default=True, type=click.Path(), help="Folder to write.")
@click.option("--min", "low", default=0.0, show_default=True, type=float, help="Smallest covered fraction of the object.")
@click.option("--max", "high", default=0.6, show_default=True, type=float, help="Largest covered fraction of the object.")
@click.option("--copies", default=1, show_default=True, type=click.IntRange(min=1), help="Differently occluded copies per frame.")
@click.option("--rects", default=1, show_default=True, type=click.IntRange(min=1), help="Rectangles per frame.")
@click.option("--seed", default=0, show_default=True, type=click.IntRange(min=0), help="Seed (same seed, same bytes).")
@click.option("--workers", default=1, show_default=True, type=click.IntRange(min=1), help="Worker processes.")
@ALLOW_PARTIAL
@executor_options
@handle_errors
def occlude_cmd(in_dir, out_dir, low, high, copies, rects, seed, allow_partial, executor):
    """Write copies of shards with black rectangles covering [--min, --max] of each object."""
    from spm_data.commands.occlude_jobs import occlude_dataset, occlusion_report

    run_with_progress(lambda bar: occlude_dataset(in_dir, out_dir, low=low, high=high, copies=copies, rects=rects,
                                                  seed=seed, progress=bar, executor=executor,
                                                  allow_partial=allow_partial),
                      occlusion_report)


@data_cli.group("import")
def import_group():
    """Turn real datasets (COIL-100, CVL, BOP, any posed-image folder) into shards."""


def _finish_import(call):
    from spm_data.formats.importing import import_report

    problems = []

    def run(bar):
        summary, found = call(bar)
        problems.extend(found)
        return summary

    run_with_progress(run, lambda summary: import_report(summary, problems))


common_import = [
    click.option("--out", default="out_imported", show_default=True, type=click.Path(), help="Folder to write."),
    click.option("--threshold", default=10, show_default=True, type=click.IntRange(0, 254),
                 help="Mask = brightest channel above this, where the data has no masks."),
    click.option("--workers", default=1, show_default=True, type=click.IntRange(min=1), help="Worker processes."),
]


def with_common(fn):
    for option in reversed(common_import):
        fn = option(fn)
    return fn


@import_group.command("coil100")
@click.argument("path", type=click.Path())
@with_common
@click.option("--elevation", default=0.0, show_default=True, help="Assumed camera elevation, degrees (not published).")
@click.option("--distance", default=1.0, show_default=True, help="Assumed camera distance, metres (not published).")
@click.option("--fov", default=30.0, show_default=True, help="Assumed vertical field of view, degrees.")
@click.option("--classes", "classes_csv", type=click.Path(), default=None, help="CSV: object id,class name.")
@executor_options
@handle_errors
def import_coil100_cmd(path, out, threshold, elevation, distance, fov, classes_csv, executor):
    """COIL-100: the extracted folder, coil-100.zip or coil-100.tar.gz."""
    from spm_data.formats.coil100 import import_coil100

    _finish_import(lambda bar: import_coil100(path, out, elevation=elevation, distance=distance, fov=fov,
                                              classes_csv=classes_csv, threshold=threshold, progress=bar,
                                              executor=executor))


@import_group.command("folder")
@click.argument("path", type=click.Path())
@click.option("--poses", "poses_csv", type=click.Path(), default=None, help="Pose table (default PATH/poses.csv).")
@with_common
@click.option("--unit", default="m", show_default=True, type=click.Choice(["m", "cm", "mm"]), help="Translation unit.")
@click.option("--euler", default="XYZ", show_default=True, help="Euler order of rx ry rz columns (scipy notation).")
@click.option("--fov", type=float, default=None, help="Vertical field of view, degrees, if the table has no fx fy cx cy.")
@click.option("--class", "class_name", default="folder", show_default=True, help="Class when the table has none.")
@click.option("--depth-unit", default="mm", show_default=True, type=click.Choice(["m", "cm", "mm"]),
              help="What one step of a uint16 depth image is.")
@executor_options
@handle_errors
def import_folder_cmd(path, poses_csv, out, threshold, unit, euler, fov, class_name, depth_unit, executor):
    """Images plus a table of per-image poses (docs/datasets.md)."""
    from spm_data.formats.posed_folder import import_folder

    _finish_import(lambda bar: import_folder(path, out, poses_csv=poses_csv, unit=unit, euler=euler, fov=fov,
                                             class_name=class_name, depth_unit=depth_unit, threshold=threshold,
                                             progress=bar, executor=executor))


@import_group.command("cvl")
@click.argument("path", type=click.Path())
@with_common
@click.option("--unit", default="mm", show_default=True, type=click.Choice(["m", "cm", "mm"]), help="Translation unit.")
@click.option("--fov", type=float, default=None, help="Vertical field of view, degrees, if tables have no fx fy cx cy.")
@executor_options
@handle_errors
def import_cvl_cmd(path, out, threshold, unit, fov, executor):
    """CVL in the assumed layout PATH/<object>/poses.csv (docs/datasets.md)."""
    from spm_data.formats.posed_folder import import_cvl

    _finish_import(lambda bar: import_cvl(path, out, unit=unit, fov=fov, threshold=threshold,
                                          progress=bar, executor=executor))


@import_group.command("bop")
@click.argument("path", type=click.Path())
@with_common
@click.option("--split", default="train_pbr", show_default=True, help="BOP split folder.")
@click.option("--crop", type=click.IntRange(min=8), default=None, help="Square crops of this size around each object.")
@click.option("--classes", "classes_csv", type=click.Path(), default=None, help="CSV: obj_id,class name.")
@executor_options
@handle_errors
def import_bop_cmd(path, out, threshold, split, crop, classes_csv, executor):
    """A BOP dataset split: one frame per (image, object)."""
    from spm_data.formats.bop import import_bop

    _finish_import(lambda bar: import_bop(path, out, split=split, crop=crop, classes_csv=classes_csv,
                                          progress=bar, executor=executor))


@data_cli.group("export")
def export_group():
    """Hand shards to other tools in their formats."""


@export_group.command("bop")
@click.argument("folder", type=click.Path())
@click.option("--out", "out_dir", required=True, type=click.Path(), help="BOP dataset folder to create.")
@click.option("--split", default="train", show_default=True,
              help="Split folder name; rgb is JPEG in *_pbr splits (as BOP's), PNG otherwise.")
@click.option("--meshes-from", "meshes_from", type=click.Path(), default=None,
              help="The folder the rendered spec's mesh paths start from (the spec's folder), if it has "
                   "moved since the render.")
@ALLOW_PARTIAL
@handle_errors
def export_bop_cmd(folder, out_dir, split, meshes_from, allow_partial):
    """Write a shard folder as a BOP dataset (one scene per object instance)."""
    from spm_data.formats.bop import export_bop

    bar = Progress()
    try:
        counts = export_bop(folder, out_dir, split=split, progress=bar, allow_partial=allow_partial,
                            meshes_from=meshes_from)
    finally:
        bar.close()
    click.echo(f"exported {counts['frames']} frames of {counts['objects']} objects in {counts['scenes']} scenes "
               f"-> {out_dir}/")
    if counts["without_model"]:
        click.echo(f"  no mesh for {len(counts['without_model'])} objects (imported, not rendered): "
                   f"{', '.join(counts['without_model'][:10])}")


@data_cli.command("merge")
@click.argument("folders", nargs=-1, type=click.Path())
@click.option("--out", "out_dir", required=True, type=click.Path(), help="Folder to write.")
@click.option("--sources", default=None, help="Keep only these sources, e.g. synthetic,coil100.")
@click.option("--classes", "renames", default=None, help="Rename classes: old=new[,old=new...].")
@click.option("--frames-per-shard", default=256, show_default=True, type=click.IntRange(min=1))
@click.option("--workers", default=1, show_default=True, type=click.IntRange(min=1), help="Worker processes.")
@ALLOW_PARTIAL
@executor_options
@handle_errors
def merge_cmd(folders, out_dir, sources, renames, frames_per_shard, allow_partial, executor):
    """Combine shard folders into one, rebalanced into full shards."""
    from spm_data.commands.merge import merge_folders, parse_renames

    keep = [s.strip() for s in sources.split(",") if s.strip()] if sources else None
    run_with_progress(lambda bar: merge_folders(folders, out_dir, sources=keep, renames=parse_renames(renames),
                                                frames_per_shard=frames_per_shard, progress=bar,
                                                executor=executor, allow_partial=allow_partial))


@data_cli.command("validate")
@click.argument("folder", type=click.Path())
@handle_errors
def validate_cmd(folder):
    """Check every shard against the schema and the manifest against the files; exit 1 on any problem."""
    from spm_data.commands.validate import validate_folder, validation_report

    problems = validate_folder(folder)
    click.echo(validation_report(folder, problems))
    if problems:
        sys.exit(1)


@data_cli.command("info")
@click.argument("path", type=click.Path())
@handle_errors
def info_cmd(path):
    """Describe a shard or a shard folder."""
    from spm_data.commands.info import describe

    click.echo(describe(path))


@data_cli.command("show")
@click.argument("shard", type=click.Path())
@click.option("--out", "out_png", default="sheet.png", show_default=True, type=click.Path(),
              help="Image to write: .png, .jpg, .jpeg, .pdf or .svg.")
@click.option("--frames", default=24, show_default=True, type=click.IntRange(min=1), help="Frames on the sheet.")
@click.option("--field", default="rgb", show_default=True,
              type=click.Choice(["rgb", "normals", "instances", "coords", "depth"]),
              help="What the tiles show: the image, or an [outputs] field in false colour.")
@handle_errors
def show_cmd(shard, out_png, frames, field):
    """Write a contact sheet of a shard's frames with their pose axes drawn."""
    from spm_data.commands.sheet import contact_sheet

    click.echo(f"wrote {contact_sheet(shard, out_png, frames=frames, field=field)}")


@data_cli.command("hist")
@click.argument("folder", type=click.Path())
@click.option("--out", "out_png", default="occlusion-hist.png", show_default=True, type=click.Path(),
              help="Image to write: .png, .jpg, .jpeg, .pdf or .svg.")
@ALLOW_PARTIAL
@handle_errors
def hist_cmd(folder, out_png, allow_partial):
    """Histogram of the occluded fractions of a shard folder."""
    from spm_data.commands.sheet import occlusion_histogram

    click.echo(f"wrote {occlusion_histogram(folder, out_png, allow_partial=allow_partial)}")
