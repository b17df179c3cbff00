"""spm_cli.data (spm-data): its commands end to end, errors in one line with exit status 1, the console
scripts as processes (the coil_folder fixture: tests/conftest.py)."""

import subprocess
import sys

from click.testing import CliRunner

from cli import data_cli
from spm_data.io.shards import read_manifest


def run(*args):
    return CliRunner().invoke(data_cli, [str(a) for a in args], catch_exceptions=False)


def test_render_info_show(small_specs_dir, tmp_path):
    out = tmp_path / "out"
    r = run("render", "--class", "cup", "--specs-dir", small_specs_dir, "--out", out, "--limit", 10)
    assert r.exit_code == 0, r.output
    assert "rendered 2 shards (10 frames)" in r.output
    r = run("render", "--class", "cup", "--specs-dir", small_specs_dir, "--out", out, "--limit", 10)
    assert "2 already complete" in r.output
    r = run("info", out)
    assert r.exit_code == 0 and "cup" in r.output and "total: 10 frames" in r.output
    r = run("info", out / "cup-00000.h5")
    assert "rgb" in r.output and "(8, 64, 64, 3)" in r.output and "azimuth" in r.output
    png = tmp_path / "sheet.png"
    r = run("show", out / "cup-00000.h5", "--out", png)
    assert r.exit_code == 0 and png.stat().st_size > 1000
    import cv2

    sheet = cv2.imread(str(png))
    assert sheet.shape[0] >= 128 and sheet.std() > 10


def test_errors_are_one_line_and_exit_1(small_specs_dir, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('class = "cup"\n[camera]\nazimuth = [0, 355, 7]\n')
    r = run("render", "--spec", bad, "--out", tmp_path / "o")
    assert r.exit_code == 1
    assert r.output.strip().count("\n") == 0 and r.output.startswith("error: ")
    assert "camera.azimuth: step 7.0 does not divide" in r.output
    assert not (tmp_path / "o").exists()
    r = run("info", tmp_path / "nothing")
    assert r.exit_code == 1 and "no such shard or folder" in r.output
    (tmp_path / "junk.h5").write_bytes(b"junk")
    r = run("show", tmp_path / "junk.h5")
    assert r.exit_code == 1 and "not an spm shard" in r.output


def test_occludes_option_errors_are_the_library_ones_with_the_flags_named(small_specs_dir, tmp_path, monkeypatch):
    """The library checks occlude's options once and names them by key (min, max, seed...); the
    command line's one line names the flags (spm_cli/support.py FLAGS)."""
    monkeypatch.setenv("SPM_PROGRESS_EVERY", "100000")   # no progress line beside the one error line
    render, out = tmp_path / "r", tmp_path / "o"
    assert run("render", "--class", "cup", "--specs-dir", small_specs_dir, "--out", render, "--limit", 4).exit_code == 0
    for args, line in [(["--max", "1.5"], "occlusion fractions must lie in [0, 1]: got --min 0.0, --max 1.5"),
                       (["--min", "0.5", "--max", "0.3"], "--min 0.5 is above --max 0.3")]:
        r = run("occlude", render, "--out", out, *args)
        assert (r.exit_code, r.output) == (1, f"error: {line}\n") and not out.exists()
    assert run("occlude", render, "--out", out, "--max", "0.6", "--seed", "1").exit_code == 0
    r = run("occlude", render, "--out", out, "--max", "0.5", "--seed", "1")
    assert (r.exit_code, r.output) == (1, f"error: {out / 'cup-00000.h5'} was made with --max 0.6, not --max 0.5; "
                                          f"write into a new --out folder or delete {out}\n")


def test_console_scripts_run_as_processes(small_specs_dir, tmp_path):
    exe = [sys.executable, "-c", "import cli; cli.data_cli()"]
    r = subprocess.run(exe + ["render", "--class", "box", "--specs-dir", str(small_specs_dir), "--out",
                              str(tmp_path / "o"), "--limit", "4", "--workers", "2"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert read_manifest(tmp_path / "o")["frames"] == 4
    r = subprocess.run([sys.executable, "-c", "import cli; cli.model_cli()", "--help"], capture_output=True, text=True)
    assert r.returncode == 0 and "Sparse Pose Manifolds" in r.stdout


def test_off_a_terminal_render_and_validate_print_progress_lines_on_stderr(small_specs_dir, tmp_path, monkeypatch):
    """A run longer than $SPM_PROGRESS_EVERY prints "LABEL: done/total UNITs, rate, time left"
    lines on stderr (CliRunner's stderr is not a terminal); stdout keeps only the summary."""
    import re
    import time

    import spm_data.pipelines.validate as validate
    from spm_cli.support import Progress

    monkeypatch.setenv("SPM_PROGRESS_EVERY", "0.01")   # rendering 10 frames takes far longer
    r = run("render", "--class", "cup", "--specs-dir", small_specs_dir, "--out", tmp_path / "out", "--limit", 10)
    assert r.exit_code == 0 and r.stdout.startswith("rendered 2 shards (10 frames)"), r.output
    lines = r.stderr.splitlines()
    assert any(re.fullmatch(r"render: \d+/10 frames, [\d.]+ frames/s(, \d+ s left)?", line) for line in lines), lines
    assert all(line.startswith("render: ") for line in lines), lines

    shown = []
    checked = validate.validate_shard

    def slow_validate_shard(path):   # lasts until a progress line was printed: a state, not a sleep
        deadline = time.monotonic() + 30
        while not shown and time.monotonic() < deadline:
            time.sleep(0.005)
        return checked(path)

    line = Progress.line
    monkeypatch.setattr(validate, "validate_shard", slow_validate_shard)
    monkeypatch.setattr(Progress, "line", lambda self: shown.append(line(self)) or shown[-1])
    r = run("validate", tmp_path / "out")
    assert r.exit_code == 0 and r.stdout.endswith("all shards valid; manifest agrees with the files\n"), r.output
    assert re.match(r"validate: 0/2 shards, 0 shards/s\n", r.stderr), r.stderr


def test_render_gpu_refusals_are_one_line_and_exit_1(small_specs_dir, tmp_path, monkeypatch):
    """The device list is injected (this machine may or may not have a GPU)."""
    from spm_data.render import pyrender_backend

    base = ["render", "--class", "cup", "--specs-dir", small_specs_dir, "--out", tmp_path / "o", "--limit", 2]
    monkeypatch.setattr(pyrender_backend, "visible_gpus", lambda: ((), "pyrender's EGL"))
    refusals = {
        ("--gpus", "0"): "error: --gpus 0: no GPU here (pyrender's EGL lists none); leave --gpus out to render on the "
                         "CPU",
        ("--gpus", "0,x"): "error: --gpus '0,x': expected GPU indices separated by commas, such as 0 or 0,1,3",
        ("--task-gpus", "1"): "error: --task-gpus is for --executor ray; on this machine, pick GPUs with --gpus",
        ("--gpus", "1", "--executor", "ray"): "error: --gpus picks this machine's GPUs (--executor local); Ray tasks "
                                              "ask for theirs with --task-gpus",
    }
    for args, line in refusals.items():
        r = run(*base, *args)
        assert r.exit_code == 1 and r.output == line + "\n", (args, r.output)
    monkeypatch.setattr(pyrender_backend, "visible_gpus", lambda: ((0, 1), "pyrender's EGL"))
    r = run(*base, "--gpus", "0,3", "--workers", 2)
    assert r.exit_code == 1 and r.output == "error: --gpus 0,3: there is no GPU 3; pyrender's EGL lists 2: 0, 1\n"
    assert not (tmp_path / "o").exists()
    assert "--gpus" in run("render", "--help").output and "--task-gpus" in run("render", "--help").output
