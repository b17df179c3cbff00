"""Command-line interface: ``spm-data`` (datasets) and ``spm`` (the model).

Each command is a thin wrapper around one library call; library errors
(SpmError) are printed as one line and exit with status 1.
"""

from __future__ import annotations

import functools
import sys
import warnings

import click

from spm_data.errors import SpmError, SpmWarning


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """The library's warnings (SpmWarning) as one ``warning:`` line on stderr."""
    if issubclass(category, SpmWarning):
        click.echo(f"warning: {message}", err=True)
    else:
        _python_showwarning(message, category, filename, lineno, file, line)


_python_showwarning = warnings.showwarning

ALLOW_PARTIAL = click.option(
    "--allow-partial", is_flag=True,
    help="Read a folder a live run is still writing, or whose manifest is missing or disagrees with its "
         "files: only the complete shards, each gap a warning (docs/reliability.md).")


def handle_errors(fn):
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        warnings.showwarning = _show_warning
        try:
            return fn(*args, **kwargs)
        except SpmError as exc:
            click.echo(f"error: {exc}", err=True)
            sys.exit(1)

    return wrapper


class Progress:
    """A tqdm bar the library can feed frame deltas (negative when a crashed shard is redone)."""

    def __init__(self, unit="frame"):
        from tqdm import tqdm

        self.bar = tqdm(total=0, unit=unit, dynamic_ncols=True, disable=None)

    @property
    def total(self):
        return self.bar.total

    @total.setter
    def total(self, value):
        self.bar.total = value
        self.bar.refresh()

    def __call__(self, n):
        self.bar.update(n)

    def close(self):
        self.bar.close()


def run_with_progress(call, report=lambda summary: summary.report()):
    """Run ``call(progress_bar)``, print its summary, exit 130 if interrupted, 1 if shards failed."""
    bar = Progress()
    try:
        summary = call(bar)
    finally:
        bar.close()
    click.echo(report(summary))
    if summary.interrupted:
        sys.exit(130)
    if summary.failed:
        sys.exit(1)


def executor_options(fn):
    """--executor/--address/--task-cpus -> an ``executor`` argument (with --workers, --recycle-after)."""
    @functools.wraps(fn)
    def wrapper(*args, executor_name, address, task_cpus, **kwargs):
        from spm_data.executor import make_executor

        kwargs["executor"] = make_executor(executor_name, workers=kwargs.get("workers", 1), address=address,
                                           task_cpus=task_cpus, recycle_after=kwargs.get("recycle_after", 0))
        return fn(*args, **kwargs)

    for option in reversed([
        click.option("--executor", "executor_name", type=click.Choice(["local", "ray"]), default="local",
                      show_default=True, help="Where shard jobs run: local processes, or Ray tasks (docs/scaling.md)."),
        click.option("--address", default=None, help="Ray cluster address (auto or HOST:PORT); default: a local "
                                                     "Ray instance with --workers CPUs."),
        click.option("--task-cpus", default=1.0, show_default=True, type=click.FloatRange(min=0.01),
                     help="CPUs each Ray task reserves (give Blender tasks its Cycles threads)."),
    ]):
        wrapper = option(wrapper)
    return wrapper


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
def render_cmd(classes, all_classes, spec_files, specs_dir, out, workers, renderer, seed, limit, recycle_after,
               executor):
    """Render classes over their camera paths into shards in --out (resumes)."""
    from spm_data.render_jobs import load_run_specs, render_dataset

    specs = load_run_specs(classes, all_classes, spec_files, specs_dir, renderer=renderer, seed=seed)
    run_with_progress(lambda bar: render_dataset(specs, out, limit=limit, workers=workers, progress=bar,
                                                 recycle_after=recycle_after, executor=executor))


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
def occlude_cmd(in_dir, out_dir, low, high, copies, rects, seed, workers, allow_partial, executor):
    """Write copies of shards with black rectangles covering [--min, --max] of each object."""
    from spm_data.occlude_jobs import occlude_dataset, occlusion_report

    run_with_progress(lambda bar: occlude_dataset(in_dir, out_dir, low=low, high=high, copies=copies, rects=rects,
                                                  seed=seed, workers=workers, progress=bar, executor=executor,
                                                  allow_partial=allow_partial),
                      occlusion_report)


@data_cli.group("import")
def import_group():
    """Turn real datasets (COIL-100, CVL, BOP, any posed-image folder) into shards."""


def _finish_import(call):
    from spm_data.importing import import_report

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
def import_coil100_cmd(path, out, threshold, workers, elevation, distance, fov, classes_csv, executor):
    """COIL-100: the extracted folder, coil-100.zip or coil-100.tar.gz."""
    from spm_data.coil100 import import_coil100

    _finish_import(lambda bar: import_coil100(path, out, elevation=elevation, distance=distance, fov=fov,
                                              classes_csv=classes_csv, threshold=threshold, workers=workers,
                                              progress=bar, executor=executor))


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
def import_folder_cmd(path, poses_csv, out, threshold, workers, unit, euler, fov, class_name, depth_unit, executor):
    """Images plus a table of per-image poses (docs/datasets.md)."""
    from spm_data.posed_folder import import_folder

    _finish_import(lambda bar: import_folder(path, out, poses_csv=poses_csv, unit=unit, euler=euler, fov=fov,
                                             class_name=class_name, depth_unit=depth_unit, threshold=threshold,
                                             workers=workers, progress=bar, executor=executor))


@import_group.command("cvl")
@click.argument("path", type=click.Path())
@with_common
@click.option("--unit", default="mm", show_default=True, type=click.Choice(["m", "cm", "mm"]), help="Translation unit.")
@click.option("--fov", type=float, default=None, help="Vertical field of view, degrees, if tables have no fx fy cx cy.")
@executor_options
@handle_errors
def import_cvl_cmd(path, out, threshold, workers, unit, fov, executor):
    """CVL in the assumed layout PATH/<object>/poses.csv (docs/datasets.md)."""
    from spm_data.posed_folder import import_cvl

    _finish_import(lambda bar: import_cvl(path, out, unit=unit, fov=fov, threshold=threshold, workers=workers,
                                          progress=bar, executor=executor))


@import_group.command("bop")
@click.argument("path", type=click.Path())
@with_common
@click.option("--split", default="train_pbr", show_default=True, help="BOP split folder.")
@click.option("--crop", type=click.IntRange(min=8), default=None, help="Square crops of this size around each object.")
@click.option("--classes", "classes_csv", type=click.Path(), default=None, help="CSV: obj_id,class name.")
@executor_options
@handle_errors
def import_bop_cmd(path, out, threshold, workers, split, crop, classes_csv, executor):
    """A BOP dataset split: one frame per (image, object)."""
    from spm_data.bop import import_bop

    _finish_import(lambda bar: import_bop(path, out, split=split, crop=crop, classes_csv=classes_csv,
                                          workers=workers, progress=bar, executor=executor))


@data_cli.group("export")
def export_group():
    """Hand shards to other tools in their formats."""


@export_group.command("bop")
@click.argument("folder", type=click.Path())
@click.option("--out", "out_dir", required=True, type=click.Path(), help="BOP dataset folder to create.")
@click.option("--split", default="train", show_default=True,
              help="Split folder name; rgb is JPEG in *_pbr splits (as BOP's), PNG otherwise.")
@click.option("--spec-dir", type=click.Path(file_okay=False), default=None,
              help="Folder of the spec whose mesh files were rendered, if not where the shards recorded it.")
@ALLOW_PARTIAL
@handle_errors
def export_bop_cmd(folder, out_dir, split, spec_dir, allow_partial):
    """Write a shard folder as a BOP dataset (one scene per object instance)."""
    from spm_data.bop import export_bop

    bar = Progress()
    try:
        counts = export_bop(folder, out_dir, split=split, progress=bar, allow_partial=allow_partial,
                            spec_dir=spec_dir)
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
def merge_cmd(folders, out_dir, sources, renames, frames_per_shard, workers, allow_partial, executor):
    """Combine shard folders into one, rebalanced into full shards."""
    from spm_data.merge import merge_folders, parse_renames

    keep = [s.strip() for s in sources.split(",") if s.strip()] if sources else None
    run_with_progress(lambda bar: merge_folders(folders, out_dir, sources=keep, renames=parse_renames(renames),
                                                frames_per_shard=frames_per_shard, workers=workers, progress=bar,
                                                executor=executor, allow_partial=allow_partial))


@data_cli.command("validate")
@click.argument("folder", type=click.Path())
@handle_errors
def validate_cmd(folder):
    """Check every shard against the schema and the manifest against the files; exit 1 on any problem."""
    from spm_data.validate import validate_folder, validation_report

    problems = validate_folder(folder)
    click.echo(validation_report(folder, problems))
    if problems:
        sys.exit(1)


@data_cli.command("info")
@click.argument("path", type=click.Path())
@handle_errors
def info_cmd(path):
    """Describe a shard or a shard folder."""
    from spm_data.info import describe

    click.echo(describe(path))


@data_cli.command("show")
@click.argument("shard", type=click.Path())
@click.option("--out", "out_png", default="sheet.png", show_default=True, type=click.Path(),
              help="Image to write: .png, .jpg, .jpeg, .pdf or .svg.")
@click.option("--frames", default=24, show_default=True, type=click.IntRange(min=1), help="Frames on the sheet.")
@handle_errors
def show_cmd(shard, out_png, frames):
    """Write a contact sheet of a shard's frames with their pose axes drawn."""
    from spm_data.sheet import contact_sheet

    click.echo(f"wrote {contact_sheet(shard, out_png, frames=frames)}")


@data_cli.command("hist")
@click.argument("folder", type=click.Path())
@click.option("--out", "out_png", default="occlusion-hist.png", show_default=True, type=click.Path(),
              help="Image to write: .png, .jpg, .jpeg, .pdf or .svg.")
@ALLOW_PARTIAL
@handle_errors
def hist_cmd(folder, out_png, allow_partial):
    """Histogram of the occluded fractions of a shard folder."""
    from spm_data.sheet import occlusion_histogram

    click.echo(f"wrote {occlusion_histogram(folder, out_png, allow_partial=allow_partial)}")


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="spm")
def model_cli():
    """spm: train and evaluate the Sparse Pose Manifolds estimator on spm-data shards."""


def _parse_roi(text):
    try:
        x, y, w, h = (int(v) for v in text.split(","))
    except ValueError:
        raise SpmError(f"--roi expects x,y,width,height in whole pixels, got {text!r}; "
                       "e.g. --roi 200,120,240,240") from None
    return x, y, w, h


@model_cli.command("train")
@click.option("--shards", required=True, type=click.Path(), help="Folder of shards (searched recursively).")
@click.option("--report", "report_dir", default=None, type=click.Path(), help="Report folder [default: SHARDS/report].")
@click.option("--protocol", type=click.Choice(["loco", "views", "instances"]), default="loco", show_default=True,
              help="loco: leave one class out; views: new views of seen objects; instances: leave one instance "
                   "out of every class (category level).")
@click.option("--runs", default=3, show_default=True, type=click.IntRange(min=1), help="Repeated runs (seeds) for sigma.")
@click.option("--workers", default=1, show_default=True, type=click.IntRange(min=1), help="Feature-extraction processes.")
@click.option("--ellipse", type=click.Choice(["pso", "direct"]), default="pso", show_default=True,
              help="Ellipse fit: Eq. 1 by particle swarm (the paper's) or the direct fit.")
@click.option("--gamma", default=8, show_default=True, type=click.IntRange(min=5), help="EM clusters per frame.")
@click.option("--estimator", "estimators", multiple=True, metavar="MODULE:CLASS",
              help="Also evaluate your estimator (fit(frames, poses), predict(frames)); repeatable. docs/estimators.md")
@ALLOW_PARTIAL
@executor_options
@handle_errors
def train_cmd(shards, report_dir, protocol, runs, workers, ellipse, gamma, estimators, allow_partial, executor):
    """Extract features (cached), evaluate SPM and the baselines, write the report and the model."""
    from spm_model.features import FeatureConfig
    from spm_model.train import train

    bar = Progress()
    try:
        result = train(shards, report_dir, protocol=protocol, runs=runs, workers=workers,
                       features=FeatureConfig(gamma=gamma, ellipse=ellipse), progress=bar, executor=executor,
                       log=lambda m: bar.bar.write(m), command="spm " + " ".join(sys.argv[1:]),
                       estimators=estimators, allow_partial=allow_partial)
    except KeyboardInterrupt:
        bar.close()
        click.echo("interrupted; features already cached are kept", err=True)
        sys.exit(130)
    bar.close()
    click.echo(result["text"])
    click.echo(f"report: {result['report']}/results.md, models: {result['model']} (SPM), "
               f"{result['reference_model']} (reference)")


@model_cli.command("evaluate")
@click.option("--model", "model_path", required=True, type=click.Path(), help="model.npz (SPM) or reference-model.npz from spm train.")
@click.option("--shards", required=True, type=click.Path(), help="Folder of shards to score it on.")
@click.option("--workers", default=1, show_default=True, type=click.IntRange(min=1), help="Feature-extraction processes.")
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
@ALLOW_PARTIAL
@executor_options
@handle_errors
def evaluate_cmd(model_path, shards, workers, as_json, allow_partial, executor):
    """Score a trained model (SPM or reference) on other shards: ±5°, sum < 5° and < 3°, errors."""
    import json

    from spm_model.train import evaluate_model

    bar = Progress()
    try:
        result = evaluate_model(model_path, shards, workers=workers, progress=bar, executor=executor,
                                allow_partial=allow_partial)
    finally:
        bar.close()
    if as_json:
        click.echo(json.dumps(result, indent=2))
        return
    click.echo(f"{'class':<12}{'frames':>8}{'±5° %':>8}{'sum<5 %':>9}{'sum<3 %':>9}{'geo med':>9}{'t med mm':>10}")
    for name, s in [*result["classes"].items(), ("all", result["all"])]:
        fmt = lambda v: "-" if v is None else f"{v:.1f}"  # noqa: E731
        click.echo(f"{name:<12}{s['frames']:>8}{fmt(s['success_tol5']):>8}{fmt(s['success_sum5']):>9}"
                   f"{fmt(s['success_sum3']):>9}{fmt(s['geodesic_median_deg']):>9}{fmt(s['translation_median_mm']):>10}")


@model_cli.command("predict")
@click.option("--model", "model_path", required=True, type=click.Path(),
              help="model.npz (SPM) or reference-model.npz from spm train.")
@click.argument("images", nargs=-1, required=True, type=click.Path())
@click.option("--roi", default=None, help="Region of interest x,y,width,height (pixels) holding the object.")
@click.option("--mask", "mask_path", default=None, type=click.Path(), help="Object mask image (non-zero = object).")
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
@handle_errors
def predict_cmd(model_path, images, roi, mask_path, as_json):
    """Print the 6-DoF pose estimate of each image (rx ry rz degrees, t metres).

    stdout: one line per image that got a pose (--json: every image, failed ones as
    {"image", "error"}); stderr: one "error: IMAGE: reason" line per image that failed.
    The other images still get their results; exit status 1 if any image failed."""
    from spm_model.train import format_predictions, prediction_errors, predict_images

    results = predict_images(model_path, images, roi=None if roi is None else _parse_roi(roi),
                             mask_path=mask_path)
    out = format_predictions(results, as_json)
    if out:
        click.echo(out)
    failed = prediction_errors(results)
    for line in failed:
        click.echo(f"error: {line}", err=True)
    if failed:
        sys.exit(1)


if __name__ == "__main__":
    data_cli()
