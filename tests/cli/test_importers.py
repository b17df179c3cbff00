"""spm_cli.importers (spm-data import): an import end to end with its skips reported and a
rerun resuming, the class map under its own name (--class-map), and the dataset as the first argument
(the coil_folder fixture: tests/conftest.py)."""

from click.testing import CliRunner

from cli import data_cli


def test_cli_import_reports_skips_and_resumes(coil_folder, tmp_path):
    args = ["import", "coil100", str(coil_folder), "--out", str(tmp_path / "o")]
    r = CliRunner().invoke(data_cli, args)
    assert r.exit_code == 0, r.output
    assert "imported 1 shard (142 frames)" in r.output
    assert "skipped 3 images:" in r.output and "missing view" in r.output and "foreign file" in r.output
    assert "truncated" in r.output
    r = CliRunner().invoke(data_cli, args)
    assert "1 already complete" in r.output
    r = CliRunner().invoke(data_cli, ["export", "bop", str(tmp_path / "o"), "--out", str(tmp_path / "b")])
    assert r.exit_code == 0 and "exported 142 frames of 2 objects in 2 scenes" in r.output
    assert "no mesh for 2 objects" in r.output
    r = CliRunner().invoke(data_cli, ["export", "bop", str(tmp_path / "o"), "--out", str(tmp_path / "b")])
    assert r.exit_code == 1 and "not empty" in r.output


def test_class_map_names_the_classes(coil_folder, tmp_path):
    (tmp_path / "classes.csv").write_text("object,class\n12,mug\n")
    r = CliRunner().invoke(data_cli, ["import", "coil100", str(coil_folder), "--out", str(tmp_path / "o"),
                                      "--class-map", str(tmp_path / "classes.csv"), "--workers", "2"])
    assert r.exit_code == 0, r.output
    info = CliRunner().invoke(data_cli, ["info", str(tmp_path / "o")]).output
    assert "mug" in info and "coil100-obj7" in info and "coil100-obj12" not in info, info  # 7 keeps its default
