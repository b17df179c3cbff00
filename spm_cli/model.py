"""The ``spm`` commands (cli.py puts them in the group): train, evaluate and apply pose estimators
on shard folders. The input (shards, images) is the first argument, every output is ``--out``."""

from __future__ import annotations

import sys

import click

from spm_cli.support import ALLOW_PARTIAL, Progress, comma_list, executor_options, handle_errors, old_spelling
from spm_data.errors import SpmError


# Seconds a plug-in's call may take (spm_model/bench/isolation.py DEFAULT_TIMEOUT; a test keeps them equal).
PLUGIN_TIMEOUT_S = 3600.0


def timeout_option(command):
    return click.option("--timeout", "timeout", default=PLUGIN_TIMEOUT_S, show_default=True, metavar="SECONDS",
                        type=click.FloatRange(min=0, min_open=True),
                        help="Seconds a plug-in's call (construct and fit, or one predict) may take; one that "
                             "takes longer is stopped and declined.")(command)


def device_option(default, what):
    """--device auto|cpu|cuda|cuda:N: where the cnn method's network runs (spm_model/methods/cnn_net.py)."""
    return click.option("--device", "device", default=default, metavar="auto|cpu|cuda|cuda:N",
                        show_default=default is not None,
                        help=f"Where {what} (auto: a GPU when torch sees one, else the CPU). A device torch "
                             "cannot use is an error." + ("" if default else " [default: auto]"))


def _parse_roi(text):
    try:
        x, y, w, h = (int(v) for v in text.split(","))
    except ValueError:
        raise SpmError(f"--roi expects x,y,width,height in whole pixels, got {text!r}; "
                       "e.g. --roi 200,120,240,240") from None
    return x, y, w, h


def _method_names(values):
    """--methods a,b --methods c -> ["a", "b", "c"] (none given: None, all); the registry's one-line error
    naming an unknown one."""
    if not values:
        return None
    from spm_model.methods.registry import check_method_names

    return check_method_names(comma_list(values), "--methods")


class RegistryOption(click.Option):
    """An option whose help names what the method registry holds, read when help is shown (the
    registry imports every method): ``{names}``, the built-in methods (--methods); ``{model_files}``,
    the model files spm train writes (--out, --model)."""

    def get_help_record(self, ctx):
        from spm_model.methods.registry import METHOD_NAMES, SAVED_MODELS

        *others, last = (f"{m.model_file} ({m.model_title})" for m in SAVED_MODELS.values())
        self.help = self.help.format(names=", ".join(METHOD_NAMES), model_files=f"{', '.join(others)} or {last}")
        return super().get_help_record(ctx)


def bop_options(command):
    """--bop-results DIR and its naming options (spm_model/pipelines/bop_output.py)."""
    for option in reversed([
        click.option("--bop-results", "bop_results", default=None, type=click.Path(),
                     help="Also write the estimates as BOP results files DIR/METHOD_DATASET-SPLIT.csv, one per "
                          "method, for bop_toolkit's eval_bop19_pose.py (docs/datasets.md)."),
        click.option("--bop-dataset", default="spm", show_default=True,
                     help="Dataset name in the results file names (letters and digits)."),
        click.option("--bop-split", default="test", show_default=True,
                     help="Split name in the results file names (letters and digits): the export's --split."),
        click.option("--bop-ids-from", default=None, type=click.Path(),
                     help="An earlier BOP export (or its objects.json) whose obj_ids to keep, as export bop "
                          "--ids-from.")]):
        command = option(command)
    return command


def _bop(bop_results, bop_dataset, bop_split, bop_ids_from):
    """The BopOutput of the --bop-* options (None without --bop-results)."""
    if bop_results is None:
        return None
    from spm_model.pipelines.bop_output import BopOutput

    return BopOutput(bop_results, bop_dataset, bop_split, bop_ids_from)


def _bop_line(result) -> None:
    if result.get("bop_results"):
        click.echo("bop results: " + ", ".join(str(p) for p in result["bop_results"]))


@click.command("train")
@click.argument("shards", metavar="SHARDS", required=False, type=click.Path())
@click.option("--out", "report_dir", default=None, type=click.Path(), cls=RegistryOption,
              help="Report folder: results.md/json, plots and the models of the methods asked for: {model_files} "
                   "[default: SHARDS/report].")
@click.option("--protocol", type=click.Choice(["loco", "views", "instances", "offgrid", "interleaved"]), default=None,
              help="loco (default; views where the data has one class): leave one class out; views: new views of "
                   "seen objects; instances: leave one instance out of every class (category level); offgrid: "
                   "train on SHARDS, test on --test (Fig. 5); interleaved: train on every other view of each "
                   "camera path, test on the views between.")
@click.option("--test", "test", default=None, type=click.Path(),
              help="Test folder of the offgrid protocol (random views, occluded): train on SHARDS, test here.")
@click.option("--train-occluded/--clean-training", "train_occluded", default=None,
              help="Whether occluded frames train too (the paper's training with noise) [default: yes, but no "
                   "under offgrid].")
@click.option("--methods", "methods", cls=RegistryOption, multiple=True, metavar="NAME[,NAME...]",
              help="Built-in methods to run (default all): {names}. Repeatable, or comma-separated.")
@click.option("--runs", default=3, show_default=True, type=click.IntRange(min=1, max=100),
              help="Repeated runs (seeds) for sigma (at most 100).")
@click.option("--ellipse", type=click.Choice(["pso", "direct"]), default="pso", show_default=True,
              help="Ellipse fit: Eq. 1 by particle swarm (the paper's) or the direct fit.")
@click.option("--gamma", default=8, show_default=True, type=click.IntRange(min=5, max=256),
              help="EM clusters per frame (at most 256).")
@click.option("--estimator", "estimators", multiple=True, metavar="MODULE:CLASS",
              help="Also evaluate your estimator (fit(frames, poses), predict(frames)); repeatable. docs/estimators.md")
@device_option("auto", "the cnn method trains and predicts")
@timeout_option
@bop_options
@ALLOW_PARTIAL
@executor_options("Feature-extraction processes")
@old_spelling("--shards", "shards", "give the folder as the first argument", required="SHARDS", type=click.Path())
@old_spelling("--report", "report_dir", "use --out", type=click.Path())
@handle_errors
def train_cmd(shards, report_dir, protocol, test, train_occluded, methods, runs, ellipse, gamma, estimators, device,
              timeout, bop_results, bop_dataset, bop_split, bop_ids_from, allow_partial, executor):
    """Extract features of the shards in SHARDS (searched recursively, cached), evaluate SPM and the
    other methods under --protocol (offgrid: test on --test), and write the report and the models to --out."""
    from spm_model.spm.features import FeatureConfig
    from spm_model.pipelines.train import train

    bar = Progress()
    try:
        result = train(shards, report_dir, protocol=protocol, runs=runs,
                       features=FeatureConfig(gamma=gamma, ellipse=ellipse), progress=bar, executor=executor,
                       log=bar.write, command="spm " + " ".join(sys.argv[1:]),
                       estimators=estimators, allow_partial=allow_partial, test=test,
                       train_occluded=train_occluded, builtins=_method_names(methods),
                       bop=_bop(bop_results, bop_dataset, bop_split, bop_ids_from), timeout=timeout,
                       model_params={"cnn": {"device": device}} if device != "auto" else None)
    except KeyboardInterrupt:
        from spm_data.jobs.outcome import exit_status

        bar.close()
        click.echo("interrupted; features already cached are kept", err=True)
        sys.exit(exit_status())   # 130 after Ctrl-C, 143 after SIGTERM
    finally:
        bar.close()
    click.echo(result["text"])
    click.echo(f"report: {result['report']}/results.md, {_models_line(result)}")
    _bop_line(result)


def _models_line(result) -> str:
    """"models: PATH (SPM), PATH (HOG templates)" for what train fitted and wrote (only the models of
    methods asked for; each named by its registry row's model title), and what it could not fit."""
    from spm_model.methods.registry import SAVED_MODELS

    written = [f"{path} ({SAVED_MODELS[name].model_title})" for name, path in result["model_files"].items()]
    missing = [f"{SAVED_MODELS[name].model_title} declined" for name, state in result["models"].items()
               if state != "written"]   # absent: not asked for, so not fitted
    *others, last = SAVED_MODELS
    none = f"none (neither {', '.join(others)} nor {last} was asked for)" if not result["models"] else "none"
    return "models: " + (", ".join(written) or none) + (f" ({'; '.join(missing)})" if missing else "")


@click.command("check-estimator")
@click.argument("spec", metavar="MODULE:CLASS")
@timeout_option
@handle_errors
def check_estimator_cmd(spec, timeout):
    """Run your estimator MODULE:CLASS through the contract `spm train --estimator` relies on, on a small
    built-in set (rendered with pyrender): one line a check; exit status 1 if any check fails."""
    from spm_model.pipelines.check_estimator import check_estimator, failed

    with Progress() as bar:
        checks = check_estimator(spec, progress=bar, log=bar.write, timeout=timeout)
    bad = failed(checks)
    click.echo(f"{len(checks)} checks, {len(bad)} failed" + ("" if bad else f"; {spec} can run in spm train"))
    if bad:
        sys.exit(1)


@click.command("evaluate")
@click.argument("shards", metavar="SHARDS", required=False, type=click.Path())
@click.option("--model", "model_path", required=True, type=click.Path(), cls=RegistryOption,
              help="{model_files}, from spm train.")
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of the table.")
@device_option(None, "a cnn model runs")
@bop_options
@ALLOW_PARTIAL
@executor_options("Feature-extraction processes")
@old_spelling("--shards", "shards", "give the folder as the first argument", required="SHARDS", type=click.Path())
@handle_errors
def evaluate_cmd(model_path, shards, as_json, device, bop_results, bop_dataset, bop_split, bop_ids_from, allow_partial,
                 executor):
    """Score a trained model (--model: a model file spm train wrote) on the shards in SHARDS: ±5°,
    sum < 5° and < 3°, median errors per class."""
    import json

    from spm_model.pipelines.evaluate import evaluate_model

    bar = Progress()
    try:
        result = evaluate_model(model_path, shards, progress=bar, executor=executor,
                                allow_partial=allow_partial, bop=_bop(bop_results, bop_dataset, bop_split,
                                                                      bop_ids_from), device=device)
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
    _bop_line(result)


@click.command("predict")
@click.argument("images", metavar="IMAGE...", nargs=-1, required=True, type=click.Path())
@click.option("--model", "model_path", required=True, type=click.Path(), cls=RegistryOption,
              help="{model_files}, from spm train.")
@click.option("--roi", default=None, help="Region of interest x,y,width,height (pixels) holding the object.")
@click.option("--mask", "mask_path", default=None, type=click.Path(), help="Object mask image (non-zero = object).")
@click.option("--json", "as_json", is_flag=True, help="Print JSON: every image, failed ones with their error.")
@device_option(None, "a cnn model runs")
@handle_errors
def predict_cmd(model_path, images, roi, mask_path, as_json, device):
    """Print the 6-DoF pose estimate of each IMAGE by the model --model (rx ry rz degrees, t metres).

    stdout: one line per image that got a pose (--json: every image, failed ones as
    {"image", "error"}); stderr: one "error: IMAGE: reason" line per image that failed.
    The other images still get their results; exit status 1 if any image failed."""
    from spm_model.pipelines.predict import format_predictions, prediction_errors, predict_images

    with Progress("image") as bar:
        results = predict_images(model_path, images, roi=None if roi is None else _parse_roi(roi),
                                 mask_path=mask_path, progress=bar, device=device)
    out = format_predictions(results, as_json)
    if out:
        click.echo(out)
    failed = prediction_errors(results)
    for line in failed:
        click.echo(f"error: {line}", err=True)
    if failed:
        sys.exit(1)
