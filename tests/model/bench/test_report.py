"""spm_model.bench.report: results.md, results.json and the plots of a tiny hand-made evaluation:
one class (cup), four frames, methods whose errors are known."""

import json

import numpy as np
import pytest

from spm_data.errors import SpmError
from spm_model.bench.metrics import accuracy_curve, pose_errors, summarise
from spm_model.bench.scoring import occlusion_rows
from spm_model.bench.report import (SCHEMA, SCHEMA_VERSION, aggregate, check_report_folder, markdown, summary_text,
                              write_error, write_report)

TRUE = np.array([[90.0, 0, 10, 0, 0, 0.6]] * 4)
# Rotation errors about z per frame: spm misses one frame by 20 degrees, knn3 two by 30, chance all by 90.
OFF = {"spm": [0, 0, 0, 20], "knn1": [0, 0, 0, 0], "knn3": [0, 0, 30, 30], "chance": [90, 90, 90, 90]}


def tiny_evaluation():
    errors = {}
    for m, off in OFF.items():
        pred = TRUE.copy()
        pred[:, 2] += off
        errors[m] = pose_errors(pred, TRUE)
    run = {"seed": 0, "overall": {m: summarise(e) for m, e in errors.items()},
           "classes": {"cup": {m: summarise(e) for m, e in errors.items()}},
           "occlusion": {m: occlusion_rows(np.zeros(4), e) for m, e in errors.items()},
           "accuracy_curve": {m: accuracy_curve(e["geodesic"], 4).tolist() for m, e in errors.items()}}
    return {"protocol": "views", "runs": [run], "eccentricity": {"cup": {"mean": 0.5, "std": 0.1, "frames": 4}},
            "classes": ["cup"], "methods": list(OFF)}


CONTEXT = {"command": "spm train --shards s", "frames": 4, "shards": "s", "train_features": 4, "query_features": 4}


def test_aggregate_is_the_mean_over_runs_with_sigma():
    evaluation = tiny_evaluation()
    evaluation["runs"].append(json.loads(json.dumps(evaluation["runs"][0])))
    evaluation["runs"][1]["overall"]["spm"]["success_tol5"] = 25.0
    summary = aggregate(evaluation)
    assert summary["protocol"] == "views" and summary["runs"] == 2
    assert list(summary["methods"]) == ["spm", "knn1", "knn3"] and summary["chance"]["success_tol5"] == 0.0
    spm = summary["methods"]["spm"]
    assert spm["success_tol5"] == 50.0 and spm["std"]["success_tol5"] == 25.0      # mean and sigma of 75 and 25
    assert spm["frames"] == 4 and spm["estimated"] == 4 and "frames" not in spm["std"]
    assert summary["occlusion"]["knn3"][0]["success_tol5"] == 50.0 and summary["occlusion"]["knn3"][1]["frames"] == 0


def test_markdown_of_a_tiny_summary_has_the_expected_rows():
    evaluation = tiny_evaluation()
    text = markdown(evaluation, aggregate(evaluation), CONTEXT)
    lines = text.splitlines()
    assert lines[0] == "# Pose benchmark (views protocol, 1 run)"
    # 4 of 4 frames: Wilson's 95% interval is [1 / (1 + z²/4), 1] = [51.0, 100]; 0 of 4: [0, 49.0].
    assert lines[2] == ("- **Best method, views protocol: KNN K=1**, 100.0% (95% CI 51.0–100.0, 4 frames) within ±5°, "
                        "above chance's 0.0% (95% CI 0.0–49.0, 4 frames) beyond both 95% intervals; geodesic median "
                        "0.0° (chance 90.0°), AUC of accuracy to 45° 100.0 (chance 0.0).")
    assert lines[3] == ("- ±5° of the others: SPM 75.0% (95% CI 30.1–95.4, 4 frames); KNN K=3 50.0% "
                        "(95% CI 15.0–85.0, 4 frames).")
    assert "Command: `spm train --shards s`" in lines
    # Table 1 (SPM, with the paper's cup numbers beside), Table 2 (KNN K=1 and K=3).
    assert ("| cup | 4 | 75.0 [30.1–95.4] | 75.0 [30.1–95.4] | 75.0 [30.1–95.4] | 0.50 | 0.10 | 86.6 | 0.87 |"
            in lines)
    assert "| cup | 4 | 100.0 [51.0–100.0] | 50.0 [15.0–85.0] | 82.6 | 82.8 |" in lines
    # Every method over all frames, chance last; per class; occlusion bins with frames only.
    rows = [line for line in lines if line.startswith(("| SPM |", "| KNN K=1 |", "| KNN K=3 |", "| chance"))]
    # Method, Estimated, Features (– where the method does not say), Coverage %, ±5° % [interval] (one run: no σ)
    assert [r.split(" | ")[:5] for r in rows[:4]] == [["| SPM", "4/4", "–", "100.0", "75.0 [30.1–95.4]"],
                                                      ["| KNN K=1", "4/4", "–", "100.0", "100.0 [51.0–100.0]"],
                                                      ["| KNN K=3", "4/4", "–", "100.0", "50.0 [15.0–85.0]"],
                                                      ["| chance (random training pose)", "4/4", "–", "100.0",
                                                       "0.0 [0.0–49.0]"]]
    assert "| cup | 4 | 75.0 [30.1–95.4] (0) | 100.0 [51.0–100.0] (0) | 50.0 [15.0–85.0] (15) | 0.0 [0.0–49.0] (90) |" \
        in lines
    assert "| 0%–10% | 4 | 75.0 [30.1–95.4] | 100.0 [51.0–100.0] | 50.0 [15.0–85.0] | 0.0 [0.0–49.0] |" in lines
    assert not any(r.startswith("| 10%–20%") for r in lines)


def test_write_report_writes_four_files_whole(tmp_path):
    summary = write_report(tiny_evaluation(), CONTEXT, tmp_path / "report")
    assert sorted(p.name for p in (tmp_path / "report").iterdir()) == ["accuracy.png", "occlusion.png",
                                                                       "results.json", "results.md"]
    payload = json.loads((tmp_path / "report" / "results.json").read_text())
    assert (payload["schema"], payload["schema_version"]) == (SCHEMA, SCHEMA_VERSION) == ("spm-results", 5)
    assert list(payload) == ["schema", "schema_version", "context", "summary", "evaluation"]
    assert payload["summary"]["methods"]["spm"]["std"]["success_tol5"] is None          # one run: no sigma
    assert payload["summary"]["best"] == "knn1" and list(payload["summary"])[:5] == ["protocol", "runs", "methods",
                                                                                     "chance", "best"]
    assert payload["summary"] == json.loads(json.dumps(summary)) and payload["context"] == CONTEXT
    assert (tmp_path / "report" / "accuracy.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = summary_text(summary).splitlines()
    assert text[0].startswith("- Best method, views protocol: KNN K=1, 100.0% (95% CI 51.0–100.0, 4 frames) within ±5°")
    assert "- Recovered by KNN K=1 (median error at most half of chance's): azimuth 0.0° (chance 90.0°); azimuth " \
           "mod 180° 0.0° (chance 90.0°)." in text
    # The method, ±5° %, sum<5 %, AUC to 45° (spm: 75% up to 20°, then 100%), geodesic median, elevation, distance.
    assert [line.rsplit(maxsplit=6)[1:] for line in text[-4:]] == [
        ["75.0", "75.0", "89.0", "0.0", "0.0", "0.0"], ["100.0", "100.0", "100.0", "0.0", "0.0", "0.0"],
        ["50.0", "50.0", "66.9", "15.0", "0.0", "0.0"], ["0.0", "0.0", "0.0", "90.0", "0.0", "0.0"]]


def test_report_folder_problems_are_one_line(tmp_path):
    (tmp_path / "notes").write_text("mine")
    assert check_report_folder(tmp_path / "new" / "report") == tmp_path / "new" / "report"
    with pytest.raises(SpmError, match=r"^report folder .*notes is a file; give a folder with --out$"):
        check_report_folder(tmp_path / "notes")
    with pytest.raises(SpmError, match=r"^report folder .*notes/r cannot be made: .*notes is a file; give a folder"):
        check_report_folder(tmp_path / "notes" / "r")
    assert str(write_error(tmp_path, OSError(28, "No space left on device"))) == (
        f"could not write the report in {tmp_path}: No space left on device; free space there or give another "
        "folder with --out")
    assert not (tmp_path / "new").exists()


def test_a_method_declined_everywhere_has_no_figures_and_its_reason_in_every_report(tmp_path):
    evaluation = tiny_evaluation()
    evaluation["runs"][0].update(splits=["all"], declined={"knn3": {"all": "needs depth: none of the 4 frames has it"}})
    summary = aggregate(evaluation)
    assert list(summary["methods"]) == ["spm", "knn1"] and "knn3" not in summary["classes"]["cup"]
    assert summary["declined"] == {"knn3": {"reason": "needs depth: none of the 4 frames has it", "splits": 1, "of": 1}}
    lines = markdown(evaluation, summary, CONTEXT).splitlines()
    assert "- KNN K=3 declined: needs depth: none of the 4 frames has it" in lines
    assert not any(line.startswith("| KNN K=3 |") for line in lines)
    assert "- KNN K=3 declined: needs depth: none of the 4 frames has it" in summary_text(summary).splitlines()
    write_report(evaluation, CONTEXT, tmp_path)
    assert json.loads((tmp_path / "results.json").read_text())["summary"]["declined"]["knn3"]["of"] == 1


def test_frames_without_an_estimate_show_as_coverage_beside_the_scores():
    evaluation = tiny_evaluation()
    pred = TRUE.copy()
    pred[3] = np.nan                      # spm: no estimate for the last frame, the three others exact
    errors = pose_errors(pred, TRUE)
    run = evaluation["runs"][0]
    run["overall"]["spm"] = {**summarise(errors), "featured": 3}
    run["classes"]["cup"]["spm"] = summarise(errors)
    run["occlusion"]["spm"][0].update(estimated=3)
    evaluation["runs"][0].update(splits=["a", "b"], declined={"spm": {"b": "predict: ValueError: boom"}})
    summary = aggregate(evaluation)
    spm = summary["methods"]["spm"]
    assert (spm["estimated"], spm["frames"], spm["coverage"], spm["featured"]) == (3, 4, 75.0, 3)
    assert summary["declined"]["spm"] == {"reason": "predict: ValueError: boom", "splits": 1, "of": 2}
    lines = markdown(evaluation, summary, CONTEXT).splitlines()
    assert [line.split(" | ")[:5] for line in lines if line.startswith("| SPM |")][0] == [
        "| SPM", "3/4", "3/4", "75.0", "75.0 [30.1–95.4]"]
    assert "| cup | 4 | 75.0 [30.1–95.4] (0) · 75% est. | 100.0 [51.0–100.0] (0) | 50.0 [15.0–85.0] (15) | " \
        "0.0 [0.0–49.0] (90) |" in lines
    assert "| 0%–10% | 4 | 75.0 [30.1–95.4] · 75% est. | 100.0 [51.0–100.0] | 50.0 [15.0–85.0] | 0.0 [0.0–49.0] |" \
        in lines
    assert "- SPM declined in 1 of 2 splits: predict: ValueError: boom" in lines


def test_a_method_that_ran_without_any_estimate_and_partly_measured_frames_are_said():
    """COIL-like frames (only rz measured): the summary says why the geodesic figures are –; a method
    that ran but estimated nothing is named, not left as a row of zeros."""
    evaluation = tiny_evaluation()
    measured = np.zeros((4, 6), bool)
    measured[:, 2] = True
    run = evaluation["runs"][0]
    for m, off in OFF.items():
        pred = TRUE.copy()
        pred[:, 2] += off
        if m == "knn3":
            pred[:] = np.nan
        run["overall"][m] = summarise(pose_errors(pred, TRUE, measured))
    lines = markdown(evaluation, aggregate(evaluation), CONTEXT).splitlines()
    assert any(line.startswith("- The test frames measure only part of the rotation") for line in lines)
    assert any(line.startswith("- KNN K=3 ran but gave no estimate for any of the 4 test frames") for line in lines)
