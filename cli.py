"""Command-line interface: ``spm-data`` (datasets) and ``spm`` (the model).

Each command is a thin wrapper around one library call; library errors
(SpmError) are printed as one line and exit with status 1.
"""

from __future__ import annotations

import functools
import sys

import click

from spm_data.errors import SpmError


def handle_errors(fn):
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
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
@handle_errors
def render_cmd(classes, all_classes, spec_files, specs_dir, out, workers, renderer, seed, limit):
    """Render classes over their camera paths into shards in --out (resumes)."""
    from spm_data.render_jobs import load_run_specs, render_dataset

    specs = load_run_specs(classes, all_classes, spec_files, specs_dir, renderer=renderer, seed=seed)
    run_with_progress(lambda bar: render_dataset(specs, out, limit=limit, workers=workers, progress=bar))


@data_cli.command("occlude")
@click.option("--in", "in_dir", default="out", show_default=True, type=click.Path(), help="Folder of shards to read.")
@click.option("--out", "out_dir", default="out_occluded", show_default=True, type=click.Path(), help="Folder to write.")
@click.option("--min", "low", default=0.0, show_default=True, type=float, help="Smallest covered fraction of the object.")
@click.option("--max", "high", default=0.6, show_default=True, type=float, help="Largest covered fraction of the object.")
@click.option("--copies", default=1, show_default=True, type=click.IntRange(min=1), help="Differently occluded copies per frame.")
@click.option("--rects", default=1, show_default=True, type=click.IntRange(min=1), help="Rectangles per frame.")
@click.option("--seed", default=0, show_default=True, type=click.IntRange(min=0), help="Seed (same seed, same bytes).")
@click.option("--workers", default=1, show_default=True, type=click.IntRange(min=1), help="Worker processes.")
@handle_errors
def occlude_cmd(in_dir, out_dir, low, high, copies, rects, seed, workers):
    """Write copies of shards with black rectangles covering [--min, --max] of each object."""
    from spm_data.occlude_jobs import occlude_dataset, occlusion_report

    run_with_progress(lambda bar: occlude_dataset(in_dir, out_dir, low=low, high=high, copies=copies, rects=rects,
                                                  seed=seed, workers=workers, progress=bar), occlusion_report)


@data_cli.command("info")
@click.argument("path", type=click.Path())
@handle_errors
def info_cmd(path):
    """Describe a shard or a shard folder."""
    from spm_data.info import describe

    click.echo(describe(path))


@data_cli.command("show")
@click.argument("shard", type=click.Path())
@click.option("--out", "out_png", default="sheet.png", show_default=True, type=click.Path(), help="PNG to write.")
@click.option("--frames", default=24, show_default=True, type=click.IntRange(min=1), help="Frames on the sheet.")
@handle_errors
def show_cmd(shard, out_png, frames):
    """Write a contact sheet of a shard's frames with their pose axes drawn."""
    from spm_data.sheet import contact_sheet

    click.echo(f"wrote {contact_sheet(shard, out_png, frames=frames)}")


@data_cli.command("hist")
@click.argument("folder", type=click.Path())
@click.option("--out", "out_png", default="occlusion-hist.png", show_default=True, type=click.Path(), help="PNG to write.")
@handle_errors
def hist_cmd(folder, out_png):
    """Histogram of the occluded fractions of a shard folder."""
    from spm_data.sheet import occlusion_histogram

    click.echo(f"wrote {occlusion_histogram(folder, out_png)}")


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="spm")
def model_cli():
    """spm: train and evaluate the Sparse Pose Manifolds estimator on spm-data shards."""


if __name__ == "__main__":
    data_cli()
