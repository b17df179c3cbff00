"""benchmarks/train_scaling.py --accuracy-only and benchmarks/spm_ablation.py write the figures
README.md and docs/spm-ablation.md quote (docs/results/measures/spm-solvers.json,
spm-ablation.json, issue 46): what they write, and the tables scripts/results_doc.py renders
from it, are the figures measured."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from tests.helpers import load_script

ROOT = Path(__file__).resolve().parents[2]


results_doc = load_script("scripts/results_doc.py", "results_doc")


def test_solver_figures_are_means_and_sigmas_over_seeds():
    scaling = load_script("benchmarks/train_scaling.py", "train_scaling")
    # rows per seed: new views sum<5, own sum<5, own sum<3, fit s, fit CPU s
    rows = {name: (np.array([[0.0, 30.0, 10.0, 1.0, 2.0], [1.0, 32.0, 12.0, 3.0, 4.0]]) + i, 1200, 500)
            for i, name in enumerate(scaling.SOLVERS)}
    found = scaling.accuracy_figures(rows, 2880)
    assert (found["frames"], found["training_frames"], found["test_frames"], found["seeds"]) == (2880, 1200, 500, 2)
    assert found["solvers"]["exact_all"] == {"new_sum5": 0.5, "new_sum5_std": 0.5, "own_sum5": 31.0,
                                             "own_sum5_std": 1.0, "own_sum3": 11.0, "own_sum3_std": 1.0,
                                             "fit_s": 2.0, "fit_cpu_s": 3.0}
    assert found["solvers"]["knn_subset"]["own_sum5"] == 33.0
    made = {"date": "2026-11-29", "command": "python benchmarks/train_scaling.py S --accuracy-only",
            "machine": {"nproc": 2}, "cpu_s": 321.4}
    table = results_doc.table_spm_solvers({"summary": found, "made": made})
    assert "| exact Eq. 5 over every training frame | 31.0 (σ 1.0) | 11.0 (σ 1.0) | 0.5 (σ 0.5) | 3.0 |" in table
    assert "re-predicting its 1,200 training frames" in table and "on 500 new views" in table
    assert "of 2,880 frames" in table and "over 2 seeds" in table and made["command"] in table
    assert "the whole command 321 CPU seconds" in table


def test_measure_without_accuracy_only_is_refused_in_one_line():
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "train_scaling.py"), "x", "--measure", "m.json"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and r.stderr.splitlines()[-1] == (
        "train_scaling.py: error: --measure goes with --accuracy-only and a shards folder")


@pytest.mark.slow
def test_the_ablation_measure_holds_the_tables_figures(instance_shards, tmp_path):
    shards = tmp_path / "shards"
    shutil.copytree(instance_shards, shards)
    measure = tmp_path / "spm-ablation.json"
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "spm_ablation.py"), "run", str(shards),
                        "--out", str(tmp_path / "out"), "--no-hires", "--no-best", "--azimuth-step", "2",
                        "--elevation-step", "1", "--projection-samples", "60", "--measure", str(measure)],
                       capture_output=True, text=True, timeout=900,
                       env={**os.environ, "SPM_PROGRESS_EVERY": "100000"})
    assert r.returncode == 0, r.stderr[-3000:]
    found = json.loads(measure.read_text())
    sub = found["summary"]["subset"]
    # 2 classes x 2 instances x 12 of the 24 azimuths x 2 elevations; the other azimuths are neighbours
    assert (sub["frames"], sub["with_neighbours"], sub["shards_frames"], sub["classes"]) == (96, 192, 192, 2)
    variants = found["summary"]["variants"]
    assert len(variants) == 12 and variants[0][0].startswith("default")
    default = variants[0][1]
    assert default["views"]["spm"]["frames"] + default["instances"]["spm"]["frames"] > 96   # views + every frame
    assert found["made"]["command"].startswith("python benchmarks/spm_ablation.py run ")
    assert set(found["summary"]["probe"]["views"]) == set("abcdez")
    # The tables printed are the doc's, rendered from the measure.
    for table in (results_doc.table_spm_ablation(found), results_doc.table_spm_ablation_probe(found)):
        assert table in r.stdout
    assert f"| {variants[0][0]} | {default['train_coverage_pct']:.0f} / {default['query_coverage_pct']:.0f} | " \
           f"{default['views']['nn']['median_deg']:.1f} |" in results_doc.table_spm_ablation(found)
    made = results_doc.table_spm_ablation_made(found)
    assert "96 subset frames (192 with their path neighbours) of 192" in made
    assert found["made"]["cpu_s"] > 0 and f"{found['made']['cpu_s']:,.0f} CPU seconds" in made
