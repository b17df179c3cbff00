"""The library call behind ``spm check-estimator MODULE:CLASS``: a plug-in run through the estimator
contract (spm_model/base/estimator.py) on a small built-in set, as scikit-learn's
``check_estimator`` does, one line a check.

The set: two procedural classes (box, cup), two instances each, 24 views of each instance at
64 x 64 px, rendered with pyrender into a temporary folder and read back as the benchmark reads
any folder (features cached, frames served as spm_model/base/frames.py serves them). The
training frames are the even views of each camera path, the test frames the odd ones (the
``interleaved`` protocol), handed over as a camera gives them, shuffled as ``spm train``'s
first run shuffles them. The plug-in runs in a process of its own that never holds a test
label (check_contract.py), each call bounded by --timeout. Checks marked FAIL break what
the benchmark relies on; notes describe the estimator without failing it. Its score is
printed beside chance's, with 95% intervals; trained on poses permuted against the images,
a plug-in that still scores above chance finds labels some other way: FAIL.
"""

from __future__ import annotations

import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spm_data.errors import SpmError, one_line

CHECK_SPEC = """
class = "{cls}"
seed = 11
[mesh]
instances = 2
[camera]
azimuth = [0, 55, 5]
elevation = [10, 15, 5]
distances = [0.6]
[image]
width = 64
height = 64
[render]
renderer = "pyrender"
frames_per_shard = 48
"""
CLASSES = ("box", "cup")


@dataclass(frozen=True)
class Check:
    """One check's outcome: ``status`` "ok", "FAIL" or "note"; ``text`` says what was checked
    and, where it failed, what happened and the fix."""

    status: str
    text: str

    def line(self) -> str:
        return f"{self.status:<5} {self.text}"


def built_in_set(folder: Path, progress=None):
    """Render the check's set into ``folder`` and return its feature table (FeatureTable)."""
    from spm_data.pipelines.render_jobs import render_dataset
    from spm_data.core.specs import parse_spec
    from spm_model.bench.feature_cache import load_features, progress_phase
    from spm_model.spm.features import FeatureConfig

    specs = [parse_spec(CHECK_SPEC.format(cls=c), name=f"check-{c}") for c in CLASSES]
    progress_phase(progress, "rendering the check set")
    try:
        render_dataset(specs, folder, progress=progress)
    except SpmError as exc:
        raise SpmError(f"cannot render the built-in set with pyrender: {one_line(exc)}") from None
    return load_features(folder, FeatureConfig(), progress=progress)


def _static_checks(ref) -> list[Check]:
    """What its description says (read in a process of its own, plugin_refs.describe): importable by
    its module path and picklable (its process imports it by that path), and a valid NEEDS."""
    out = [Check("ok" if ref.unpicklable is None else "FAIL", "importable by its module path, for its own process"
                 + ("" if ref.unpicklable is None else f": {ref.unpicklable}"))]
    out.append(Check("ok", f"declares what it needs ({ref.NEEDS})") if ref.needs_error is None else
               Check("FAIL", f"declares what it needs: {ref.needs_error.split(': ', 1)[1]}"))
    return out


def _score(table, rows, out) -> tuple:
    """(rate % within ±5°, 95% interval (low, high) or None, frames estimated) of ``out`` for ``rows``."""
    from spm_model.bench.metrics import pose_errors, tolerance_rate, wilson_interval

    errors = pose_errors(out, table.pose[rows], table.label_measured[rows])
    rate = tolerance_rate(errors["rotation_max"])
    return rate, wilson_interval(rate, int((~np.isnan(errors["rotation_max"])).sum())), \
        int(np.isfinite(errors["rotation_max"]).sum())


def _rate(score) -> str:
    rate, ci, _ = score
    return f"{rate:.1f}% [{ci[0]:.1f}–{ci[1]:.1f}]" if ci else f"{rate:.1f}%"


def run_checks(plugin, table, log=lambda line: None, timeout: float | None = None) -> list[Check]:
    """Every check of ``plugin`` (a PluginRef, or a class: then described by its module path, in a
    process of its own) on the check set ``table``, each passed to ``log`` as it is made.
    The plug-in runs in a process of its own (check_contract.py), as ``spm train`` runs it: training
    frames (even views) and poses, test frames (odd views) as a camera gives them in the order
    ``spm train``'s first run serves them; each call of it bounded by ``timeout`` seconds."""
    from spm_model.base.frames import Frames, read_camera_frames
    from spm_model.bench.isolation import EstimatorProcess, Lost
    from spm_model.bench.plugin_refs import PluginRef, describe
    from spm_model.methods.baselines import ChancePose

    if not isinstance(plugin, PluginRef):
        spec = f"{plugin.__module__}:{plugin.__qualname__}"
        plugin = describe([spec], timeout, strict=False)[spec]
    done: list[Check] = []

    def add(check: Check) -> None:
        done.append(check)
        log(check.line())

    for check in _static_checks(plugin):
        add(check)
    even = np.asarray(table.path_index) % 2 == 0
    train, test = np.flatnonzero(even), np.flatnonzero(~even)
    test = test[np.random.default_rng(0).permutation(len(test))]   # as fitting.fit_predict, run 1 (seed 0)
    frames, poses = Frames(table, train), table.pose[train].copy()
    camera = read_camera_frames(table, test)
    permuted = poses[np.random.default_rng(1).permutation(len(poses))]
    predictions, call = {}, "construct"
    child = EstimatorProcess("spm_model.pipelines.check_contract:serve_checks")
    try:
        child.send(("checks", plugin, frames, poses, camera, permuted))
        while True:
            header, arrays = child.reply(plugin.__name__, "", timeout)
            if header.get("kind") == "call":
                call = str(header.get("what"))
            elif header.get("kind") == "check":
                add(Check(str(header["status"]), str(header["text"])))
            elif header.get("kind") == "predictions" and arrays and arrays[0].shape == (len(test), 6):
                predictions[str(header.get("set"))] = arrays[0].astype(np.float64)
            elif header.get("kind") == "end":
                break
    except Lost as lost:
        add(Check("FAIL", f"{call}: {lost.why}"))
    finally:
        child.close()
    chance = _score(table, test, ChancePose(seed=0).fit(frames, poses).predict(camera))
    if "test" in predictions:
        mine = _score(table, test, predictions["test"])
        add(Check("note", f"on this set: {mine[2]} of {len(test)} test frames estimated, {_rate(mine)} within ±5° "
                          f"(chance {_rate(chance)}; 95% intervals; the views between the training views, 5° "
                          "from one)"))
    if "permuted" in predictions:
        noise = _score(table, test, predictions["permuted"])
        above = noise[1] is not None and chance[1] is not None and noise[1][0] > chance[1][1]
        add(Check("FAIL" if above else "ok",
                  f"trained on poses permuted against the images, it scores as chance does ({_rate(noise)}; chance "
                  f"{_rate(chance)})" + (": it finds labels some other way than the images (files, order, "
                                          "memory); estimate from the frames alone" if above else "")))
    return done


def check_estimator(spec: str, *, progress=None, log=lambda line: None, timeout: float | None = None) -> list[Check]:
    """Run the plug-in ``spec`` ('MODULE:CLASS') through the contract (run_checks); every Check, each
    also passed to ``log`` (one line) as it is made. ModelError (one line) when it cannot be loaded.
    timeout: seconds each call of the plug-in may take (None: the benchmark's default)."""
    from spm_model.bench.feature_cache import progress_phase
    from spm_model.bench.isolation import DEFAULT_TIMEOUT
    from spm_model.bench.plugin_refs import describe

    timeout = DEFAULT_TIMEOUT if timeout is None else timeout
    ref = describe([spec], timeout, strict=False)[spec]   # imported in a process of its own, not here
    folder = Path(tempfile.mkdtemp(prefix="spm-check-estimator-"))
    try:
        table = built_in_set(folder / "set", progress)
        progress_phase(progress, "checks", None, None)
        return run_checks(ref, table, log, timeout)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def failed(checks: list[Check]) -> list[Check]:
    return [c for c in checks if c.status == "FAIL"]


__all__ = ["Check", "check_estimator", "failed", "run_checks"]
