"""spm_model.bench.report_tables: results.md renders as GFM tables; docs/results-schema.md is made
from METRICS."""

from spm_model.bench.report import aggregate
from spm_model.bench.report_tables import markdown
from tests.model.bench.test_report import CONTEXT, tiny_evaluation


def test_results_md_tables_render_as_gfm_tables():
    from markdown_it import MarkdownIt

    evaluation = tiny_evaluation()
    text = markdown(evaluation, aggregate(evaluation), CONTEXT)
    tokens = MarkdownIt("commonmark").enable("table").parse(text)
    tables = [t for t in tokens if t.type == "table_open"]
    pipe_blocks = [b for b in text.split("\n\n") if b.startswith("| ")]
    assert len(tables) == len(pipe_blocks) >= 5          # every pipe block is a table, none left as text
    assert "Surface errors" not in text                 # no mesh known: no table of dashes
    header = next(i for i, t in enumerate(tokens) if t.type == "thead_open")
    cells = [t for t in tokens[header:] if t.type == "th_open"]
    assert len(cells) > 10


def test_a_table_with_one_cell_too_many_in_its_delimiter_is_not_a_table():
    from markdown_it import MarkdownIt

    bad = "| a | b |\n|---|---|---|\n| 1 | 2 |\n"       # the shape results.md had before
    assert not any(t.type == "table_open" for t in MarkdownIt("commonmark").enable("table").parse(bad))


def test_the_schema_doc_lists_every_metric_as_made_from_the_list(tmp_path):
    from pathlib import Path

    from spm_model.bench.metrics import METRICS
    from spm_model.bench.report_tables import schema_rows, update_schema_doc

    doc = Path(__file__).resolve().parents[3] / "docs" / "results-schema.md"
    copy = tmp_path / "schema.md"
    copy.write_text(doc.read_text())
    assert update_schema_doc(copy) is False, "run: python -m spm_model.bench.report_tables"
    # 2 header, frames, estimated, surface, ci95, std
    assert all(f"| `{m.key}` |" in doc.read_text() for m in METRICS) and len(schema_rows()) == len(METRICS) + 7


def test_paper_columns_of_dashes_alone_are_not_printed():
    from spm_model.bench.report_tables import _paper_columns_kept

    header = ["Class", "Frames", "K=1 %", "Paper K=1 %", "Paper K=3 %"]
    assert _paper_columns_kept(header, [["scan", 9, "40.0", "–", "–"]]) == (["Class", "Frames", "K=1 %"],
                                                                             [["scan", 9, "40.0"]])
    kept = [["cup", 9, "40.0", "88.2", "–"], ["scan", 9, "40.0", "–", "–"]]
    assert _paper_columns_kept(header, kept) == (header[:4], [r[:4] for r in kept])


def test_lengths_not_in_metres_are_said_under_the_intro():
    from spm_model.bench.report_tables import _unit_line

    assert _unit_line({}) == [] and _unit_line({"length_unit": "m"}) == []
    assert _unit_line({"length_unit": "capture unit"})[0].startswith("**Lengths**: the shards hold the capture's "
                                                                       "world units (imported without `--scale`)")
