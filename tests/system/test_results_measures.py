"""The measurements the docs quote that are not reports (docs/results/measures/*.json:
{{measure:NAME:PATH}} in docs/results/results.md.in, and measure-table blocks in docs/method.md,
scripts/results_doc.py): each is quoted, says how it was made (date,
the command of a script in the repository, wall time, machine), and its script computes what
it says (benchmarks/spm_vector_distance.py on vectors with known distances)."""

import shlex
from pathlib import Path

import numpy as np
import pytest

from spm_model.spm.features import FEATURE_VERSION
from tests.helpers import load_script

ROOT = Path(__file__).resolve().parents[2]


results_doc = load_script("scripts/results_doc.py", "results_doc")
vector_distance = load_script("benchmarks/spm_vector_distance.py", "spm_vector_distance")
MEASURES = results_doc.load_measures()


def test_every_measure_is_quoted_and_every_quoted_one_exists():
    template = (ROOT / "docs" / "results" / "results.md.in").read_text()
    in_blocks = {m.group(2) for doc in results_doc.BLOCK_DOCS for m in results_doc.BLOCK.finditer(doc.read_text())}
    assert results_doc.used_measures(template) | in_blocks == set(MEASURES) and MEASURES
    assert "measure" not in results_doc.used_snapshots(template)


@pytest.mark.parametrize("name", sorted(MEASURES))
def test_a_measure_says_how_it_was_made(name):
    made = MEASURES[name]["made"]
    assert made["date"][:2] == "20" and made["wall_s"] > 0 and made["machine"]["cpu"]
    assert made["feature_version"] == FEATURE_VERSION
    script = shlex.split(made["command"])[1]
    assert shlex.split(made["command"])[0] == "python" and (ROOT / script).is_file()


def test_a_measure_placeholder_reads_its_summary_and_made_block():
    name = "spm-vectors"
    assert results_doc.resolve(f"measure:{name}:made.date", {}) == MEASURES[name]["made"]["date"]
    assert results_doc.resolve(f"measure:{name}:frames:,", {}) == f"{MEASURES[name]['summary']['frames']:,}"
    assert results_doc.resolve(f"measure:{name}:own:.3f", {}) == f"{MEASURES[name]['summary']['own']:.3f}"


def test_vector_distances_are_medians_over_frames_with_both_vectors():
    # class a: queries 0.1 from their own training vectors, training vectors 1 apart in x
    train = np.array([[0.0, 0], [1, 0], [2, 0], [np.nan, 0], [5, 5], [5, 6]])
    query = train + [0.1, 0]
    query[4] = [np.nan, 5]
    found = vector_distance.distances(train, query, np.array(["a", "a", "a", "a", "b", "b"]), seed=0)
    # frame 3 has no training vector, frame 4 no query vector: class b keeps one frame, no pair
    assert found["frames"] == 3 and found["classes"]["a"]["frames"] == 3 and "b" not in found["classes"]
    assert found["own"] == pytest.approx(0.1)
    assert found["classes"]["a"]["own"] == pytest.approx(0.1)
    # every partner is another frame of class a: 1 or 2 apart, the query 0.1 off
    assert 0.9 - 1e-9 <= found["classes"]["a"]["other"] <= 2.1 + 1e-9 and found["train_other"] >= 1.0 - 1e-9


def test_docs_measure_tables_are_rendered_from_their_measures():
    for doc in results_doc.BLOCK_DOCS:
        text = doc.read_text()
        assert results_doc.fill_blocks(text, MEASURES) == text, f"{doc}: run python scripts/results_doc.py blocks"
    method = (ROOT / "docs" / "method.md").read_text()
    assert "<!-- measure-table:n3m-small-set -->" in method


def test_a_measure_table_is_filled_from_the_figures():
    measure = {"summary": {key: {"clean": {"frames": 8, "within_5": 6, "estimated": 7, "from_markers": 5,
                                           "from_ransac": 2},
                                 "hidden": {"frames": 8, "within_5": 0, "estimated": 0, "from_markers": 0,
                                            "from_ransac": 0}}
                           for key in ("n3m", "n3m-fallback", "sift-pnp")}}
    text = "before\n<!-- measure-table:n3m-small-set -->\nstale\n<!-- /measure-table -->\nafter\n"
    filled = results_doc.fill_blocks(text, {"n3m-small-set": measure})
    assert "stale" not in filled and filled.startswith("before\n") and filled.endswith("after\n")
    assert "| `sift-pnp` | 75.0% (87.5%) | 0.0% (0.0%) | 5 / 2; 0 / 0 |" in filled
    with pytest.raises(results_doc.PlaceholderError, match="no measure table 'other'"):
        results_doc.fill_blocks("<!-- measure-table:other -->\n<!-- /measure-table -->", {})
