"""Outputs that cannot be written: an existing file or folder in the way, an unsupported
image type, a read-only folder, a full disk. Each is one ``error:`` line, exit status 1,
and nothing left behind; read-only shard folders still train (per-user feature cache).

Read-only folders are chmod 0o555. Root ignores permissions (CI runs as root), so as root
``read_only`` also makes every write under them raise PermissionError, as it would for
anyone else; ``disk_full`` lets files be created but every write to them raise ENOSPC.
"""

import builtins
import contextlib
import errno
import gc
import hashlib
import io
import os
import shutil
import sys
import warnings
from pathlib import Path

import pytest
from click.testing import CliRunner

from cli import data_cli, model_cli
from spm_data.io.shards import write_manifest
from spm_model.bench import feature_cache
from spm_model.spm.features import FeatureConfig

FAST = FeatureConfig(ellipse="direct")
IMAGE_TYPES = ".png, .jpg, .jpeg, .pdf, .svg"
WRITE_FLAGS = os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_TRUNC | os.O_APPEND


def _under(path, folders) -> bool:
    if isinstance(path, int):
        return False
    real = Path(os.path.realpath(os.fsdecode(path)))
    return any(real == f or f in real.parents for f in folders)


def _writing(mode) -> bool:
    return bool(set(mode) & set("wax+"))


@contextlib.contextmanager
def read_only(*folders):
    """Make ``folders`` read-only for the duration (chmod 0o555, restored after)."""
    folders = [Path(f).resolve() for f in folders]
    for f in folders:
        f.chmod(0o555)
    with pytest.MonkeyPatch.context() as mp:
        if os.geteuid() == 0:
            def denied(path):
                raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), os.fsdecode(path))

            real = {name: getattr(os, name) for name in ("mkdir", "open", "access", "replace", "rename", "unlink",
                                                         "remove", "rmdir")}
            real_open = builtins.open

            def guard(name, *paths_at):
                def call(*args, **kwargs):
                    if any(_under(args[i], folders) for i in paths_at if i < len(args)):
                        denied(args[paths_at[-1]])
                    return real[name](*args, **kwargs)
                return call

            def os_open(path, flags, *args, **kwargs):
                if flags & WRITE_FLAGS and _under(path, folders):
                    denied(path)
                return real["open"](path, flags, *args, **kwargs)

            def access(path, mode, *args, **kwargs):
                if mode & os.W_OK and _under(path, folders):
                    return False
                return real["access"](path, mode, *args, **kwargs)

            def open_(file, mode="r", *args, **kwargs):
                if isinstance(file, (str, bytes, os.PathLike)) and _writing(mode) and _under(file, folders):
                    denied(file)
                return real_open(file, mode, *args, **kwargs)

            for name in ("mkdir", "unlink", "remove", "rmdir"):
                mp.setattr(os, name, guard(name, 0))
            for name in ("replace", "rename"):
                mp.setattr(os, name, guard(name, 0, 1))
            mp.setattr(os, "open", os_open)
            mp.setattr(os, "access", access)
            mp.setattr(builtins, "open", open_)
            mp.setattr(io, "open", open_)
        try:
            yield
        finally:
            for f in folders:
                f.chmod(0o755)


class _FullDisk:
    """A file whose writes fail as on a full disk."""

    def __init__(self, fh):
        self._fh = fh

    def write(self, data):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def fileno(self):  # Pillow writes to a file's descriptor when it has one, past write()
        raise io.UnsupportedOperation("fileno")

    def __getattr__(self, name):
        return getattr(self._fh, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._fh.close()


@contextlib.contextmanager
def disk_full(folder):
    """Files opened for writing under ``folder`` are created, but every write to them raises ENOSPC."""
    folders = [Path(folder).resolve()]
    real_open = builtins.open

    def open_(file, mode="r", *args, **kwargs):
        fh = real_open(file, mode, *args, **kwargs)
        if isinstance(file, (str, bytes, os.PathLike)) and _writing(mode) and _under(file, folders):
            return _FullDisk(fh)
        return fh

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(builtins, "open", open_)
        mp.setattr(io, "open", open_)
        yield


@contextlib.contextmanager
def unraisable():
    """Collect what Python would print as 'Exception ignored in ...' (e.g. a half-written zip
    file's __del__ on a full disk): a traceback on the user's terminal, after the error line.
    Drop the command's result inside the block, so that what it holds is collected here."""
    seen, hook = [], sys.unraisablehook
    sys.unraisablehook = lambda u: seen.append(f"{u.object!r}: {u.exc_type.__name__}: {u.exc_value}")
    try:
        yield seen
        gc.collect()
    finally:
        sys.unraisablehook = hook


def tree(folder) -> dict:
    """Every file and folder under ``folder`` (relative name: size, or None for a folder)."""
    folder = Path(folder)
    return {str(p.relative_to(folder)): (None if p.is_dir() else p.stat().st_size) for p in folder.rglob("*")}


def run(cli, *args):
    """The command's result; an uncaught exception (a traceback for the user) fails the test.
    Warnings already shown in this process are shown again, as in the command's own process."""
    with warnings.catch_warnings():
        return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)


def assert_error(result, message):
    assert result.exit_code == 1, result.output
    assert result.stderr == f"error: {message}\n"
    assert result.stdout == ""


@pytest.fixture
def shards(model_shards, tmp_path):
    """One shard of model_shards (with a manifest) in a folder of its own, without cached features."""
    folder = tmp_path / "shards"
    folder.mkdir()
    shutil.copy(sorted(Path(model_shards).glob("*.h5"))[0], folder)
    write_manifest(folder)
    return folder


def cache_hash(folder) -> str:
    return hashlib.sha256(str(Path(folder).resolve()).encode()).hexdigest()[:16]


# --------------------------------------------------------------------------- spm-data export bop

def test_export_onto_an_existing_file(shards, tmp_path):
    out = tmp_path / "bop"
    out.write_text("mine")
    before = tree(tmp_path)
    assert_error(run(data_cli, "export", "bop", shards, "--out", out),
                 f"{out} is a file; give --out a new folder to export into")
    assert tree(tmp_path) == before and out.read_text() == "mine"


def test_export_into_a_read_only_folder(shards, tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    before = tree(tmp_path)
    with read_only(locked):
        result = run(data_cli, "export", "bop", shards, "--out", locked / "bop")
    assert_error(result, f"cannot create {locked}/bop: {locked} is read-only; give --out a folder in a writable place")
    assert tree(tmp_path) == before


def test_export_on_a_full_disk_leaves_nothing(shards, tmp_path):
    out = tmp_path / "new" / "bop"   # its parent is made too, and must go again
    before = tree(tmp_path)
    with disk_full(tmp_path / "new"):
        result = run(data_cli, "export", "bop", shards, "--out", out)
    assert_error(result, f"could not export to {out}: No space left on device; nothing was written; free space there")
    assert tree(tmp_path) == before


# --------------------------------------------------------------------------- spm-data show / hist

def image_command(command, shards):
    """(CLI arguments before --out, the default file name) of ``show`` or ``hist``."""
    if command == "show":
        return ["show", sorted(shards.glob("*.h5"))[0]], "sheet.png"
    return ["hist", shards], "occlusion-hist.png"


@pytest.mark.parametrize("command", ["show", "hist"])
def test_image_onto_an_existing_folder(command, shards, tmp_path):
    args, example = image_command(command, shards)
    folder = tmp_path / "pictures"
    folder.mkdir()
    before = tree(tmp_path)
    assert_error(run(data_cli, *args, "--out", folder),
                 f"{folder} is a folder; give an image file name such as {folder}/{example}")
    assert tree(tmp_path) == before


@pytest.mark.parametrize("command", ["show", "hist"])
@pytest.mark.parametrize("name, got", [("sheet.gif", "unsupported extension '.gif'"), ("sheet", "no extension"),
                                       ("sheet.h5", "unsupported extension '.h5'")])
def test_image_of_an_unsupported_type(command, name, got, shards, tmp_path):
    args, _ = image_command(command, shards)
    before = tree(tmp_path)
    out = tmp_path / "new" / name
    assert_error(run(data_cli, *args, "--out", out), f"{out}: {got}; give a file name ending in {IMAGE_TYPES}")
    assert tree(tmp_path) == before


@pytest.mark.parametrize("command", ["show", "hist"])
def test_image_under_a_file(command, shards, tmp_path):
    args, _ = image_command(command, shards)
    (tmp_path / "notes").write_text("mine")
    before = tree(tmp_path)
    out = tmp_path / "notes" / "sheet.png"
    assert_error(run(data_cli, *args, "--out", out),
                 f"cannot write {out}: {tmp_path}/notes is a file; give --out a path in a folder")
    assert tree(tmp_path) == before


@pytest.mark.parametrize("command", ["show", "hist"])
def test_image_into_a_read_only_folder(command, shards, tmp_path):
    args, _ = image_command(command, shards)
    locked = tmp_path / "locked"
    locked.mkdir()
    before = tree(tmp_path)
    with read_only(locked):
        result = run(data_cli, *args, "--out", locked / "sub" / "x.png")
    assert_error(result, f"cannot write {locked}/sub/x.png: {locked} is read-only; give --out a path in a "
                         "writable folder")
    assert tree(tmp_path) == before


@pytest.mark.parametrize("command", ["show", "hist"])
@pytest.mark.parametrize("suffix", [".png", ".jpg", ".pdf", ".svg"])
def test_image_on_a_full_disk_leaves_nothing(command, suffix, shards, tmp_path):
    args, _ = image_command(command, shards)
    out = tmp_path / "new" / f"x{suffix}"   # its folder is made too, and must go again
    before = tree(tmp_path)
    with disk_full(tmp_path / "new"):
        result = run(data_cli, *args, "--out", out)
    assert_error(result, f"could not write {out}: No space left on device; free space there")
    assert tree(tmp_path) == before
    # With room, every supported type is written whole, replacing what was there.
    out.parent.mkdir()
    out.write_text("old")
    result = run(data_cli, *args, "--out", out)
    assert result.exit_code == 0 and result.stdout == f"wrote {out}\n", result.output
    assert out.stat().st_size > 1000 and sorted(os.listdir(out.parent)) == [out.name]


# --------------------------------------------------------------------------- spm train / evaluate: the report

def test_train_report_onto_a_file(shards, tmp_path):
    report = tmp_path / "report"
    report.write_text("mine")
    before = tree(tmp_path)
    assert_error(run(model_cli, "train", shards, "--out", report),
                 f"report folder {report} is a file; give a folder with --out")
    assert tree(tmp_path) == before   # before any work: not even the feature cache was started


def test_train_report_under_a_file(shards, tmp_path):
    (tmp_path / "notes").write_text("mine")
    before = tree(tmp_path)
    report = tmp_path / "notes" / "report"
    assert_error(run(model_cli, "train", shards, "--out", report),
                 f"report folder {report} cannot be made: {tmp_path}/notes is a file; give a folder with --out")
    assert tree(tmp_path) == before


def test_train_report_in_a_read_only_folder(shards, tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    before = tree(tmp_path)
    with read_only(locked):
        result = run(model_cli, "train", shards, "--out", locked / "report")
    assert_error(result, f"report folder {locked}/report cannot be written: {locked} is read-only; give a writable "
                         "folder with --out")
    assert tree(tmp_path) == before


def test_train_default_report_beside_read_only_shards(shards, tmp_path):
    before = tree(tmp_path)
    with read_only(shards):
        result = run(model_cli, "train", shards)
    assert_error(result, f"report folder {shards}/report cannot be written: {shards} is read-only; give a writable "
                         "folder with --out")
    assert tree(tmp_path) == before


# --------------------------------------------------------------------------- the feature cache

def test_user_cache_root(monkeypatch, tmp_path):
    monkeypatch.setenv("SPM_CACHE_DIR", str(tmp_path / "mine"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert feature_cache.user_cache_root() == tmp_path / "mine"
    monkeypatch.delenv("SPM_CACHE_DIR")
    assert feature_cache.user_cache_root() == tmp_path / "xdg" / "spm" / "features"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert feature_cache.user_cache_root() == tmp_path / "home" / ".cache" / "spm" / "features"
    folder = feature_cache.user_cache_folder(tmp_path / "s")
    assert folder == feature_cache.user_cache_root() / cache_hash(tmp_path / "s")


def test_feature_cache_on_a_full_disk_leaves_nothing(shards, tmp_path):
    before = tree(tmp_path)
    shard = sorted(shards.glob("*.h5"))[0]
    cache = shards / ".spm-features"
    with unraisable() as ignored:
        with disk_full(cache):
            result = run(model_cli, "train", shards, "--out", tmp_path / "report", "--ellipse",
                         "direct", "--protocol", "views")
        code, stdout, stderr = result.exit_code, result.stdout, result.stderr
        del result
    assert ignored == []
    assert (code, stdout) == (1, "")
    assert stderr == (f"error: feature extraction failed for 1 shard(s); first: {shard.name}: could not write the "
                      f"feature cache {cache}/{shard.stem}-{FAST.key()}.npz: No space left on device; free space "
                      "there\n")
    assert tree(tmp_path) == before   # not even the cache folder it made


def test_no_writable_feature_cache_is_one_line(shards, tmp_path, monkeypatch):
    user = tmp_path / "user-cache"
    user.mkdir()
    monkeypatch.setenv("SPM_CACHE_DIR", str(user))
    before = tree(tmp_path)
    with read_only(shards, user):
        result = run(model_cli, "train", shards, "--out", tmp_path / "report", "--protocol", "views")
    assert_error(result, f"cannot cache features: neither {shards}/.spm-features (Permission denied) nor "
                         f"{user}/{cache_hash(shards)} (Permission denied) is writable; set SPM_CACHE_DIR to a "
                         "writable folder")
    assert tree(tmp_path) == before


@pytest.fixture(scope="module")
def read_only_run(model_shards, tmp_path_factory):
    """``spm train`` on a read-only copy of model_shards (features cached under
    XDG_CACHE_HOME), then ``spm evaluate`` of its model on the same folder."""
    root = tmp_path_factory.mktemp("read-only")
    folder = root / "shards"
    shutil.copytree(model_shards, folder, ignore=shutil.ignore_patterns(".spm-features", "report"))
    shards_before = tree(folder)
    with pytest.MonkeyPatch.context() as mp:
        mp.delenv("SPM_CACHE_DIR", raising=False)
        mp.setenv("XDG_CACHE_HOME", str(root / "xdg"))
        with read_only(folder):
            trained = run(model_cli, "train", folder, "--out", root / "report", "--runs", "1",
                          "--protocol", "views", "--ellipse", "direct", "--methods", "spm")
            mp.setattr(feature_cache, "frames_features", lambda *a, **k: pytest.fail("features extracted again"))
            evaluated = run(model_cli, "evaluate", folder, "--model", root / "report" / "model.npz")
    return {"root": root, "shards": folder, "trained": trained, "evaluated": evaluated,
            "shards_before": shards_before, "shards_after": tree(folder)}


def test_train_and_evaluate_on_read_only_shards_use_the_user_cache(read_only_run):
    r = read_only_run
    cache = r["root"] / "xdg" / "spm" / "features" / cache_hash(r["shards"])
    warning = (f"warning: cannot write the feature cache {r['shards']}/.spm-features (Permission denied); caching "
               f"features in {cache} instead (set SPM_CACHE_DIR to choose another folder)")
    for result in (r["trained"], r["evaluated"]):
        assert result.exit_code == 0, result.output
        assert result.stderr.splitlines() == [warning]
    assert "No method is called best here (views protocol): chance did not run" in r["trained"].stdout
    assert r["evaluated"].stdout.splitlines()[-1].startswith("all")
    assert r["shards_after"] == r["shards_before"]          # nothing written beside the shards
    names = sorted(p.name for p in cache.iterdir())
    assert names == sorted(f"{p.stem}-{FAST.key()}.npz" for p in r["shards"].glob("*.h5"))


def test_report_on_a_full_disk_leaves_nothing(read_only_run):
    r = read_only_run
    before = tree(r["root"])
    report = r["root"] / "new" / "report"
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("XDG_CACHE_HOME", str(r["root"] / "xdg"))   # features cached by read_only_run
        mp.setattr(feature_cache, "frames_features", lambda *a, **k: pytest.fail("features extracted again"))
        with unraisable() as ignored:
            with read_only(r["shards"]), disk_full(r["root"] / "new"):
                result = run(model_cli, "train", r["shards"], "--out", report, "--runs", "1",
                             "--protocol", "views", "--ellipse", "direct", "--methods", "spm")
            code, stderr = result.exit_code, result.stderr
            del result
    assert code == 1, stderr
    warning = stderr.splitlines()[0]
    assert stderr == (f"{warning}\nerror: could not write the report in {report}: No space left on device; free "
                      "space there or give another folder with --out\n")
    assert warning.startswith("warning: cannot write the feature cache")
    assert tree(r["root"]) == before
    assert not ignored, ignored  # no "Exception ignored in ZipFile.__del__" after the error line
