"""The ``spm-data`` commands (cli.py puts them in the group): make, occlude, merge, check, look at
and export datasets. Each is a thin wrapper around one library call; importers are in importers.py.

The grammar: the input (a folder, a shard) is the first argument, every output is ``--out``."""

from __future__ import annotations

import sys

import click

from spm_cli.support import (ALLOW_PARTIAL, Group, Progress, comma_list, executor_options, handle_errors,
                             old_spelling, run_with_progress)
from spm_data.render import renderer_names


@click.command("render")
@click.option("--class", "classes", multiple=True,
              help="Class to render (its spec is render_specs/CLASS.toml). Repeatable.")
@click.option("--all", "all_classes", is_flag=True, help="Render every spec in the specs folder.")
@click.option("--spec", "spec_files", multiple=True, type=click.Path(), help="A spec file to render. Repeatable.")
@click.option("--specs-dir", type=click.Path(), default=None, help="Where --class/--all look for specs "
                                                                   "[default: render_specs/].")
@click.option("--out", default="out", show_default=True, type=click.Path(), help="Folder to write the shards to.")
@click.option("--renderer", type=click.Choice(renderer_names()), default=None, help="Override the spec's renderer.")
@click.option("--seed", type=click.IntRange(min=0), default=None,
              help="Override the spec's seed [default: the spec's own seed, so a spec always renders the same].")
@click.option("--limit", type=click.IntRange(min=1, max=10**7), default=None,
              help="At most N frames per class, spread over views (at most 10,000,000).")
@executor_options("Render processes", recycle_after=16,
                  task_cpus="Give a Blender task its Cycles threads (render.blender.threads).")
@click.option("--gpus", default=None, metavar="0,1,...",
              help="GPUs to render on, one per worker in turn (--executor local) [default: every GPU; none: "
                   "the CPU]. pyrender: at most 4 GL contexts a GPU ($SPM_CONTEXTS_PER_GPU), --workers' other work "
                   "on their threads.")
@click.option("--task-gpus", default=0.0, show_default=True, type=click.FloatRange(min=0.0),
              help="GPUs each Ray task reserves (--executor ray; 0.25: four tasks share one).")
@handle_errors
def render_cmd(classes, all_classes, spec_files, specs_dir, out, renderer, seed, limit, executor, gpus, task_gpus):
    """Render classes (--class, --all, --spec) over their camera paths into shards in --out; a rerun resumes."""
    from spm_data.pipelines.render_gpus import render_executor
    from spm_data.pipelines.render_jobs import load_run_specs, render_dataset

    specs = load_run_specs(classes, all_classes, spec_files, specs_dir, renderer=renderer, seed=seed)
    executor = render_executor(executor, gpus, task_gpus, specs)
    run_with_progress(lambda bar: render_dataset(specs, out, limit=limit, progress=bar, executor=executor))


@click.command("occlude")
@click.argument("in_dir", metavar="FOLDER", required=False, type=click.Path())
@click.option("--out", "out_dir", default="out_occluded", show_default=True, type=click.Path(),
              help="Folder to write the occluded shards to.")
@click.option("--min", "low", default=0.0, show_default=True, type=float,
              help="Smallest covered fraction of the object.")
@click.option("--max", "high", default=0.6, show_default=True, type=float,
              help="Largest covered fraction of the object.")
@click.option("--copies", default=1, show_default=True, type=click.IntRange(min=1, max=100),
              help="Differently occluded copies per frame (at most 100: each copy is the whole dataset again).")
@click.option("--rects", default=1, show_default=True, type=click.IntRange(min=1), help="Rectangles per frame.")
@click.option("--seed", default=0, show_default=True, type=click.IntRange(min=0), help="Seed (same seed, same bytes).")
@ALLOW_PARTIAL
@executor_options("Occluding processes")
@old_spelling("--in", "in_dir", "give the folder as the first argument", required="FOLDER", type=click.Path())
@handle_errors
def occlude_cmd(in_dir, out_dir, low, high, copies, rects, seed, allow_partial, executor):
    """Write copies of the shards in FOLDER with black rectangles covering --min..--max of each object."""
    from spm_data.pipelines.occlude_jobs import occlude_dataset, occlusion_report

    run_with_progress(lambda bar: occlude_dataset(in_dir, out_dir, low=low, high=high, copies=copies, rects=rects,
                                                  seed=seed, progress=bar, executor=executor,
                                                  allow_partial=allow_partial),
                      occlusion_report)


@click.command("merge")
@click.argument("folders", metavar="FOLDER...", nargs=-1, type=click.Path())
@click.option("--out", "out_dir", required=True, type=click.Path(), help="Folder to write the merged shards to.")
@click.option("--sources", "sources", multiple=True, metavar="NAME[,NAME...]",
              help="Keep only frames of these sources, e.g. synthetic,coil100. Repeatable, or comma-separated.")
@click.option("--rename", "renames", multiple=True, metavar="OLD=NEW",
              help="Rename a class (OLD=NEW, or several as OLD=NEW,OLD2=NEW2). Repeatable.")
@click.option("--frames-per-shard", default=256, show_default=True, type=click.IntRange(min=1, max=65536),
              help="Frames in each merged shard (the last one may hold fewer; at most 65,536).")
@ALLOW_PARTIAL
@executor_options("Merging processes")
@old_spelling("--classes", "renames", "use --rename OLD=NEW")
@handle_errors
def merge_cmd(folders, out_dir, sources, renames, frames_per_shard, allow_partial, executor):
    """Combine the shard folders FOLDER... into --out, rebalanced into full shards."""
    from spm_data.pipelines.merge import merge_folders, parse_renames

    keep = comma_list(sources) or None
    run_with_progress(lambda bar: merge_folders(folders, out_dir, sources=keep,
                                                renames=parse_renames(",".join(renames)),
                                                frames_per_shard=frames_per_shard, progress=bar,
                                                executor=executor, allow_partial=allow_partial))


@click.command("validate")
@click.argument("folder", type=click.Path())
@handle_errors
def validate_cmd(folder):
    """Check every shard in FOLDER against the schema and the manifest against the files; exit 1 on any problem."""
    from spm_data.pipelines.validate import validate_folder, validation_report

    with Progress("shard") as progress:
        problems = validate_folder(folder, progress)
    click.echo(validation_report(folder, problems))
    if problems:
        sys.exit(1)


@click.command("info")
@click.argument("path", metavar="SHARD_OR_FOLDER", type=click.Path())
@handle_errors
def info_cmd(path):
    """Print what a shard or a shard folder holds: classes, frames, fields, the spec it came from.
    Exit 1 (after the description) when a folder is not whole: a listed shard missing or damaged,
    an unlisted shard, no manifest."""
    from spm_data.pipelines.info import check_noted, info_text

    text = info_text(path)
    click.echo(text)
    check_noted(path, text)


@click.command("show")
@click.argument("shard", type=click.Path())
@click.option("--out", "out_png", default="sheet.png", show_default=True, type=click.Path(),
              help="Image to write: .png, .jpg, .jpeg, .pdf or .svg.")
@click.option("--frames", default=24, show_default=True, type=click.IntRange(min=1, max=1024),
              help="Frames on the sheet (at most 1,024).")
@click.option("--field", default="rgb", show_default=True,
              type=click.Choice(["rgb", "normals", "instances", "coords", "depth"]),
              help="What the tiles show: the image, or an [outputs] field in false colour.")
@click.option("--tile", default=256, show_default=True, type=click.IntRange(min=16, max=2048),
              help="Longer side of each tile in pixels: frames of any size are scaled to it.")
@handle_errors
def show_cmd(shard, out_png, frames, field, tile):
    """Write a contact sheet of SHARD's frames with their pose axes drawn, to check the labels by eye."""
    from spm_data.pipelines.figures import contact_sheet

    click.echo(f"wrote {contact_sheet(shard, out_png, frames=frames, field=field, tile=tile)}")


@click.command("hist")
@click.argument("folder", type=click.Path())
@click.option("--out", "out_png", default="occlusion-hist.png", show_default=True, type=click.Path(),
              help="Image to write: .png, .jpg, .jpeg, .pdf or .svg.")
@ALLOW_PARTIAL
@handle_errors
def hist_cmd(folder, out_png, allow_partial):
    """Write a histogram of the occluded fractions of the frames in FOLDER."""
    from spm_data.pipelines.figures import occlusion_histogram

    click.echo(f"wrote {occlusion_histogram(folder, out_png, allow_partial=allow_partial)}")


export_group = Group("export", help="Hand shards to other tools in their formats (BOP).")


@export_group.command("bop")
@click.argument("folder", type=click.Path())
@click.option("--out", "out_dir", required=True, type=click.Path(), help="BOP dataset folder to create.")
@click.option("--split", default="train", show_default=True,
              help="Split folder name; rgb is JPEG in *_pbr splits (as BOP's), PNG otherwise.")
@click.option("--meshes-from", "meshes_from", type=click.Path(), default=None,
              help="The folder the rendered spec's mesh paths start from (the spec's folder), if it has "
                   "moved since the render (shards made before the mesh store only).")
@click.option("--ids-from", "ids_from", type=click.Path(), default=None,
              help="A previous export (or its objects.json): the objects it lists keep their obj_ids, new "
                   "ones are numbered after its largest.")
@click.option("--no-distractors", "no_distractors", is_flag=True,
              help="Leave 3-D distractors out (by default each is an object of its own in its frames).")
@ALLOW_PARTIAL
@handle_errors
def export_bop_cmd(folder, out_dir, split, meshes_from, ids_from, no_distractors, allow_partial):
    """Write the shard folder FOLDER as a BOP dataset in --out (one scene per object instance)."""
    from spm_data.formats.bop.export import export_bop

    bar = Progress()
    try:
        counts = export_bop(folder, out_dir, split=split, progress=bar, allow_partial=allow_partial,
                            meshes_from=meshes_from, ids_from=ids_from, include_distractors=not no_distractors)
    finally:
        bar.close()
    others = f" (of which {counts['distractors']} distractors)" if counts.get("distractors") else ""
    click.echo(f"exported {counts['frames']} frames of {counts['objects']} objects{others} in {counts['scenes']} "
               f"scenes -> {out_dir}/")
    if counts["without_model"]:
        click.echo(f"  no mesh for {len(counts['without_model'])} objects (imported, not rendered):")
        for name in counts["without_model"]:   # one line each: which objects have no model in models/
            click.echo(f"  {name}: no model; ground truth image-only (objects.json \"ground_truth\")")
