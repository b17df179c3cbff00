"""Tests mirror the library: every module with logic (a def or a class) has a test file at
its mirrored path, and every test file outside tests/system/ names a module that exists.

    spm_data/errors.py                -> tests/test_errors.py
    spm_data/<layer>/<module>.py      -> tests/<layer>/test_<module>.py   (also io/shards/...)
    spm_data/<layer>/__init__.py      -> tests/<layer>/test_<layer>.py    (a package's own logic)
    spm_data/__init__.py              -> tests/test_spm_data.py           (once it has logic of its own)
    spm_model/<layer>/<module>.py     -> tests/model/<layer>/test_<module>.py
    spm_cli/<module>.py               -> tests/cli/test_<module>.py       (the command line)
    cli.py                            -> tests/test_cli.py                (a top-level module, like errors.py)

The click commands are spm_cli/ and mirror like any other (spm_cli/data.py -> tests/cli/test_data.py).

Tests that exercise many modules at once (hostile reads, interruptions, layers, ...) live in
tests/system/ under names that say what they check."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TESTS = ROOT / "tests"
# package (or module) -> its folder under tests/
PACKAGES = {"spm_data": (), "spm_model": ("model",), "spm_cli": ("cli",), "cli.py": ()}

# Modules with logic that have no test file of their own, each with the reason. Keep it
# short: a module without any def or class (re-exports, constants) needs no entry.
EXEMPT: dict[str, str] = {}


def has_logic(path: Path) -> bool:
    """Whether a module defines anything (a function or a class, at any depth)."""
    tree = ast.parse(path.read_text())
    return any(isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) for node in ast.walk(tree))


def mirror(module: Path) -> Path:
    """The test file of a library module (a path relative to the repository root)."""
    if len(module.parts) == 1:  # a top-level module: cli.py
        return Path("tests", f"test_{module.stem}.py")
    package, *folders, name = module.with_suffix("").parts
    folders = [*PACKAGES[package], *folders]
    if name == "__init__":
        name = folders[-1] if folders else package
    return Path("tests", *folders, f"test_{name}.py")


def library_modules() -> list[Path]:
    return sorted(p.relative_to(ROOT) for package in PACKAGES
                  for p in ([ROOT / package] if package.endswith(".py") else (ROOT / package).rglob("*.py")))


def test_every_module_with_logic_has_its_test_file():
    missing = []
    for module in library_modules():
        if str(module) in EXEMPT or not has_logic(ROOT / module):
            continue
        test = ROOT / mirror(module)
        if not test.is_file() or "\ndef test_" not in test.read_text():
            missing.append(f"{module} -> {mirror(module)}")
    assert missing == []


def test_every_test_file_mirrors_a_module():
    """No test file named after a module that was moved or renamed (tests/system/ aside)."""
    mirrored = {mirror(m) for m in library_modules()}
    stray = [str(p.relative_to(ROOT)) for p in sorted(TESTS.rglob("test_*.py"))
             if "system" not in p.relative_to(TESTS).parts[:1] and p.relative_to(ROOT) not in mirrored]
    assert stray == []


def test_exemptions_are_real_modules_with_logic():
    assert [m for m in EXEMPT if not (ROOT / m).is_file() or not has_logic(ROOT / m)] == []


def test_the_mirror_maps_as_documented():
    assert mirror(Path("spm_data/errors.py")) == Path("tests/test_errors.py")
    assert mirror(Path("spm_data/io/shards/reader.py")) == Path("tests/io/shards/test_reader.py")
    assert mirror(Path("spm_data/render/__init__.py")) == Path("tests/render/test_render.py")
    assert mirror(Path("spm_model/pipelines/train.py")) == Path("tests/model/pipelines/test_train.py")
    assert mirror(Path("cli.py")) == Path("tests/test_cli.py") and Path("cli.py") in library_modules()
    assert mirror(Path("spm_cli/support.py")) == Path("tests/cli/test_support.py")
    assert mirror(Path("spm_data/__init__.py")) == Path("tests/test_spm_data.py")
    assert mirror(Path("spm_model/__init__.py")) == Path("tests/model/test_model.py")
    assert has_logic(ROOT / "spm_data/errors.py") and not has_logic(ROOT / "spm_data/io/shards/__init__.py")
