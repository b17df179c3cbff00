"""spm_model.bench.protocols: protocols (splits), the plug-in path and the reference estimator against chance."""

import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from cli import model_cli
from spm_model.bench.feature_cache import FeatureTable, load_features
from spm_model.spm.estimator import ModelError
from spm_model.bench.protocols import evaluate, splits
from spm_model.spm.features import FeatureConfig
from tests.helpers import note

FAST = FeatureConfig(ellipse="direct")


def instance_table():
    classes = np.repeat(["car", "cup"], 30)
    instance = np.array([f"r:{c}/{i}" for c, i in zip(classes, np.tile(np.repeat([0, 1, 2], 10), 2))])
    instance[30:] = np.where(instance[30:] == "r:cup/2", "r:cup/1", instance[30:])  # cup: 2 instances, car: 3
    return FeatureTable({"class_name": classes, "instance": instance, "path_index": np.tile(np.arange(10), 6)})


def test_instances_leave_one_instance_of_every_class_out():
    t = instance_table()
    folds = splits(t, "instances", seed=0)
    assert len(folds) == 3                                   # car has 3 instances
    tested = np.concatenate([test for _, _, test in folds])
    assert sorted(tested.tolist()) == list(range(60))        # every frame tested once per run
    for _, train, test in folds:
        assert not set(t.instance[train]) & set(t.instance[test])
        per_class = {c: set(t.instance[test][t.class_name[test] == c]) for c in ("car", "cup")}
        assert len(per_class["car"]) == 1 and len(per_class["cup"]) <= 1
        assert set(t.class_name[train]) == {"car", "cup"}    # a tested class is still trained on
    assert [s[2].tolist() for s in splits(t, "instances", seed=0)] == [f.tolist() for _, _, f in folds]
    assert [s[2].tolist() for s in splits(t, "instances", seed=1)] != [f.tolist() for _, _, f in folds]
    lonely = t.subset(t.instance != "r:cup/1")               # cup keeps one instance
    with pytest.raises(ModelError, match=r"at least 2 instances of every class; 'cup' has 1"):
        splits(lonely, "instances", seed=0)


def test_splits_never_share_a_view():
    from spm_model.bench.feature_cache import FeatureTable

    n = 40
    poses = np.column_stack([np.zeros((n, 2)), np.tile(np.arange(10) * 5.0, 4), np.tile([[0, 0, 0.6]], (n, 1))])
    t = FeatureTable({"class_name": np.array(["a"] * 20 + ["b"] * 20), "instance": np.array(["i"] * 20 + ["j"] * 20),
                      "path_index": np.tile(np.arange(10), 4), "pose": poses})   # each view twice (an occluded copy)
    (_, train, test), = splits(t, "views", seed=3)
    key = lambda i: (t.instance[i], t.path_index[i])  # noqa: E731
    assert len(train) + len(test) == n and not {key(i) for i in train} & {key(i) for i in test}
    loco = splits(t, "loco", seed=0)
    assert [c for c, _, _ in loco] == ["a", "b"] and set(t.class_name[loco[0][1]]) == {"b"}
    with pytest.raises(ModelError, match="at least 2 classes"):
        splits(t.subset(t.class_name == "a"), "loco", seed=0)


def test_identical_poses_of_an_instance_are_one_view():
    from spm_data.core.poses import camera_pose, pose_to_label

    # A grid with azimuth 0..360 in 30-degree steps: views 0 and 12 are the same pose.
    labels = np.array([pose_to_label(*(x[None] for x in camera_pose(az, 10.0, 0.0, 0.6)))[0]
                       for az in range(0, 361, 30)])
    t = FeatureTable({"class_name": np.array(["a"] * 13), "instance": np.array(["i"] * 13),
                      "path_index": np.arange(13), "pose": labels})
    apart = 0
    for seed in range(60):
        (_, train, test), = splits(t, "views", seed=seed, held_out=0.3)
        apart += (0 in test) != (12 in test)
    assert apart == 0
    from spm_model.bench.protocols import view_groups

    groups = view_groups(t)
    assert groups[12] == groups[0] == "i#0" and len(set(groups)) == 12


@pytest.mark.slow  # the full benchmark (loco_report: every built-in method, 2 runs)
def test_a_plugged_in_estimator_is_scored_beside_every_built_in_method(loco_report, plugin_module):
    # loco_report (tests/conftest.py): every built-in method and MeanPose, scored together by train().
    evaluation = loco_report[0]["evaluation"]
    seen = [json.loads(line) for line in (loco_report[1].parent / "notes.jsonl").read_text().splitlines()]
    assert seen == [{"rgb": [[128, 128, 3], "uint8"], "mask": "bool", "K": [3, 3], "n": 96, "poses": [96, 6]}] * 6
    overall = evaluation["runs"][0]["overall"]
    assert set(overall) == {"spm", "knn1", "knn3", "pca", "ls", "n3m", "sift-pnp", "smm", "template", "cnn", "chance",
                            "MeanPose"}
    assert overall["MeanPose"]["frames"] == 144 and overall["MeanPose"]["estimated"] == 144


def test_a_plugged_in_estimator_gets_frames_and_is_scored_through_the_cli(model_shards, plugin_module, tmp_path,
                                                                          notes):
    runner = CliRunner()
    report = tmp_path / "report"
    # Beside one cheap built-in (beside every one: the test above).
    r = runner.invoke(model_cli, ["train", str(model_shards), "--out", str(report), "--runs", "1",
                                  "--ellipse", "direct", "--methods", "knn1", "--estimator", "my_pose:MeanPose"])
    assert r.exit_code == 0, r.output
    assert notes() == [{"rgb": [[128, 128, 3], "uint8"], "mask": "bool", "K": [3, 3], "n": 96, "poses": [96, 6]}] * 3
    payload = json.loads((report / "results.json").read_text())
    assert payload["schema_version"] == 5 and "MeanPose" in payload["summary"]["methods"]
    summary = payload["summary"]["methods"]["MeanPose"]
    assert summary["frames"] == 144 and summary["estimated"] == 144
    assert "| MeanPose |" in (report / "results.md").read_text()
    # A plug-in that breaks the contract is declined with its reason; the other methods are scored.
    r = runner.invoke(model_cli, ["train", str(model_shards), "--out", str(tmp_path / "r1"), "--runs", "1",
                                  "--ellipse", "direct", "--methods", "knn1", "--estimator", "my_pose:WrongShape"])
    assert r.exit_code == 0, r.output
    why = "predict: estimator WrongShape: predict(frames) must return (48, 6) labels"
    assert f"- WrongShape declined: {why}" in r.output
    payload = json.loads((tmp_path / "r1" / "results.json").read_text())["summary"]
    assert list(payload["methods"]) == ["knn1"] and payload["declined"]["WrongShape"]["reason"].startswith(why)
    assert payload["declined"]["WrongShape"]["splits"] == payload["declined"]["WrongShape"]["of"] == 3
    for spec, message in (("my_pose", "--estimator expects MODULE:CLASS"),
                          ("no_such_module:X", "cannot import no_such_module"),
                          ("my_pose:Nope", "Nope is not a class in my_pose")):
        r = runner.invoke(model_cli, ["train", str(model_shards), "--out", str(tmp_path / "r2"),
                                      "--runs", "1", "--ellipse", "direct", "--methods", "knn1", "--estimator", spec])
        assert r.exit_code == 1 and message in r.output and "Traceback" not in r.output, (spec, r.output)
        assert sum(line.startswith("error:") for line in r.output.splitlines()) == 1


def test_the_reference_estimator_beats_chance_on_new_views_and_instances(instance_shards):
    table = load_features(instance_shards, FAST)
    params = {"features": FAST, "projection_samples": 60}
    only = ["template", "chance"]  # the methods asserted on (the others would only cost time)
    views = evaluate(table, "views", runs=1, model_params=params, builtins=only)["runs"][0]["overall"]
    ref, chance = views["template"], views["chance"]
    # New views of seen objects: the adjacent 5-degree view is found almost always. (Chance is
    # about 10% here: 48 views per instance, of which a +-5 degree box holds up to 9.)
    assert ref["success_tol5"] >= 80 and ref["success_tol5"] >= chance["success_tol5"] + 60, \
        (ref["success_tol5"], chance["success_tol5"])
    assert ref["geodesic_median_deg"] <= 6 and ref["median_error"]["distance_mm"] <= 1
    assert ref["auc_45"] >= chance["auc_45"] + 40
    instances = evaluate(table, "instances", runs=1, model_params=params, builtins=only)["runs"][0]["overall"]
    # New instances of a class: still far above a random training pose.
    assert instances["template"]["success_tol5"] >= instances["chance"]["success_tol5"] + 20, instances["template"]
    assert instances["template"]["surface"]["add_s_recall"] > instances["chance"]["surface"]["add_s_recall"]


def test_splits_on_two_workers_give_the_results_of_one(model_shards, tmp_path):
    from spm_data.jobs import make_executor
    from spm_model.bench.feature_cache import load_features as load

    shards = tmp_path / "s"
    shutil.copytree(model_shards, shards)
    table = load(shards, FAST)
    params = {"features": FAST, "projection_samples": 60}
    kwargs = dict(runs=2, model_params=params, builtins=["spm", "template", "pca", "chance"])
    one = evaluate(table, "loco", **kwargs)
    said = []
    two = evaluate(table, "loco", **kwargs, executor=make_executor(workers=2),
                   source=(str(shards), None, FAST, False), report=said.append)
    assert json.dumps(one["runs"], sort_keys=True) == json.dumps(two["runs"], sort_keys=True)
    classes = [tested for tested, _, _ in splits(table, "loco", 0)]
    assert [line.split(" (")[0] for line in said] == [f"run {r}: loco test {c}" for r in (1, 2) for c in classes]


def test_split_workers_share_the_feature_memo_beside_the_feature_cache(model_shards, tmp_path):
    from spm_model.base import feature_memo
    from spm_model.bench import protocols
    from spm_model.bench.feature_cache import load_features as load

    shards = tmp_path / "s"
    shutil.copytree(model_shards, shards)
    load(shards, FAST)
    try:
        protocols._table((str(shards), None, FAST, False))
        assert feature_memo._folder[0] == shards / ".spm-features" / "memo"
    finally:
        feature_memo.use_folder(None)
        protocols._TABLES.clear()


class CountedMeanPose:
    """A DETERMINISTIC plug-in that notes its fits (the ``notes`` fixture)."""
    DETERMINISTIC = True

    def fit(self, frames, poses):
        note("fit")
        self.mean_ = np.asarray(poses).mean(axis=0)
        return self

    def predict(self, frames):
        return np.tile(self.mean_, (len(frames), 1))


def test_deterministic_methods_are_fitted_in_the_first_run_only_when_splits_repeat(model_shards, monkeypatch, notes):
    from spm_model.bench import protocols

    table = load_features(model_shards, FAST)
    kwargs = dict(runs=3, model_params={"features": FAST}, builtins=["pca", "template", "chance"],
                  estimators={"counted": CountedMeanPose})
    reused = evaluate(table, "loco", **kwargs)
    assert len(notes()) == 3                               # 3 classes, once each
    # Every method reused: the later runs fit and read nothing, and still report every method.
    only = evaluate(table, "loco", runs=2, model_params={"features": FAST}, builtins=["pca"])
    assert only["runs"][1]["overall"] == only["runs"][0]["overall"] and list(only["runs"][1]["overall"]) == ["pca"]
    monkeypatch.setattr(protocols, "SAME_SPLITS_EVERY_RUN", ())
    refitted = evaluate(table, "loco", **kwargs)
    assert len(notes()) == 3 + 9                           # 3 classes x 3 runs
    assert json.dumps(reused["runs"], sort_keys=True) == json.dumps(refitted["runs"], sort_keys=True)
    assert list(reused["runs"][2]["overall"]) == ["pca", "template", "chance", "counted"]
    # chance is seeded: it is fitted in every run and differs between runs.
    runs = reused["runs"]
    assert runs[0]["overall"]["template"] == runs[2]["overall"]["template"]
    assert runs[0]["overall"]["chance"] != runs[1]["overall"]["chance"]


class BlasThreadsPose(CountedMeanPose):
    """A plug-in that notes the BLAS threads its fit runs with."""
    DETERMINISTIC = False

    def fit(self, frames, poses):
        from threadpoolctl import threadpool_info

        note(max(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"))
        return super().fit(frames, poses)


def test_benchmark_jobs_run_on_one_blas_thread_whatever_the_process_has(model_shards, notes):
    from threadpoolctl import threadpool_info, threadpool_limits

    table = load_features(model_shards, FAST)
    with threadpool_limits(limits=2, user_api="blas"):
        outside = max(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas")
        evaluate(table, "views", runs=1, model_params={"features": FAST}, builtins=[],
                 estimators={"probe": BlasThreadsPose})
    assert outside == 2 and notes() == [1, "fit"]


def test_interleaved_trains_on_every_other_view_and_tests_the_views_between():
    t = instance_table()
    (what, train, test), = splits(t, "interleaved", seed=0)
    assert what == "every other view" and len(train) + len(test) == 60
    assert set(t.path_index[train]) == {0, 2, 4, 6, 8} and set(t.path_index[test]) == {1, 3, 5, 7, 9}
    assert [s.tolist() for s in splits(t, "interleaved", seed=5)[0][1:]] == [train.tolist(), test.tolist()]


def test_final_models_fitted_on_two_workers_are_those_fitted_here(model_shards, tmp_path):
    """One job per saved model, handed out after the splits; a cnn model comes back from its worker
    (pickled, without its torch module) with the arrays it has when fitted in this process."""
    from spm_data.jobs import make_executor
    from spm_model.bench.feature_cache import load_features as load

    shards = tmp_path / "s"
    shutil.copytree(model_shards, shards)
    table = load(shards, FAST)
    small = {"steps": 40, "epochs": 100, "batch": 16, "width": 4, "embed": 8, "threads": 1, "device": "cpu"}
    kwargs = dict(runs=1, model_params={"features": FAST, "cnn": small}, builtins=["template", "cnn", "chance"],
                  final=True)
    here = evaluate(table, "views", **kwargs)["final_models"]
    there = evaluate(table, "views", **kwargs, executor=make_executor(workers=2),
                     source=(str(shards), None, FAST, False))["final_models"]
    assert list(here[0]) == list(there[0]) == ["template", "cnn"]   # report order, whichever ended first
    assert here[1] == there[1] == {}
    assert np.array_equal(here[0]["template"].codes_, there[0]["template"].codes_)
    a, b = here[0]["cnn"], there[0]["cnn"]
    assert all(np.array_equal(a.net_[k], b.net_[k]) for k in a.net_) and np.array_equal(a.embeddings_, b.embeddings_)
    assert np.array_equal(a.hog_codes_, b.hog_codes_)


def test_final_model_jobs_merge_in_report_order_with_every_declined_reason():
    from spm_model.bench.protocols import _merged

    outputs = [({"cnn": "net"}, {}), ({"template": None}, {"template": "RuntimeError: boom"}), ({"spm": "rbf"}, {})]
    fitted, declined = _merged(outputs, ("spm", "template", "cnn"))
    assert list(fitted.items()) == [("spm", "rbf"), ("template", None), ("cnn", "net")]
    assert declined == {"template": "RuntimeError: boom"}
    assert _merged([], ()) == ({}, {})
