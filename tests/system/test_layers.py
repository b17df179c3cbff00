"""The layers of docs/architecture.md, kept by parsing the code: imports go downward only,
no import cycles, no module over MAX_LINES, and no Blender or OpenGL outside the registered
renderer backends (spm_data.render.RENDERERS)."""

import ast
import subprocess
import sys
from pathlib import Path

from spm_data.render import RENDERERS

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("spm_data", "spm_model", "spm_cli", "cli.py")
# Lowest first; a module may import its own layer and those below it, never above.
LAYERS = ("spm_data.errors", "spm_data.version", "spm_data.io", "renderer registry", "spm_data.core",
          "spm_data.render", "spm_data.jobs", "spm_data.formats", "spm_data.pipelines", "spm_model.errors",
          "spm_model.base", "spm_model.spm", "spm_model.methods", "spm_model.bench", "spm_model.pipelines", "spm_cli",
          "cli")
# The registry (spm_data/render/__init__.py) and the backends' settings modules sit below core,
# which reads them for the specs; the Renderer base and the backends sit above it.
REGISTRY = {"spm_data.render"} | {b.settings.__module__ for b in RENDERERS.values() if b.settings}
BACKENDS = {b.module for b in RENDERERS.values()}
MAX_LINES = 350


def module_files() -> dict:
    """Dotted module name -> file, for every module of the library."""
    found = {}
    for package in PACKAGES:
        for path in [ROOT / package] if package.endswith(".py") else sorted((ROOT / package).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def modules() -> list:
    return list(module_files())


def imports_of(path: Path, known) -> set:
    """The library modules ``path`` imports, at the top or inside functions (lazy imports count)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
        out |= {n for n in names if n in known}
    return out


def layer(module: str) -> int:
    if module in REGISTRY:
        return LAYERS.index("renderer registry")
    if module == "spm_data":   # the package itself: its errors and version (the rest of its face is lazy)
        return LAYERS.index("spm_data.version")
    if module == "spm_model":  # likewise, at the bottom of its own layers
        return LAYERS.index("spm_model.base")
    return max(i for i, prefix in enumerate(LAYERS) if module == prefix or module.startswith(prefix + "."))


def graph() -> dict:
    files = module_files()
    return {m: imports_of(p, files) - {m} for m, p in files.items()}


def upward_imports(g: dict) -> list:
    return [f"{m} (layer {LAYERS[layer(m)]}) imports {d} (layer {LAYERS[layer(d)]})"
            for m, deps in sorted(g.items()) for d in sorted(deps) if layer(d) > layer(m)]


def import_cycles(g: dict) -> list:
    state, cycles = {}, []

    def visit(m, stack):
        state[m] = "open"
        for d in sorted(g.get(m, ())):
            if state.get(d) == "open":
                cycles.append(" -> ".join(stack[stack.index(d):] + [d]))
            elif d not in state:
                visit(d, stack + [d])
        state[m] = "done"

    for m in sorted(g):
        if m not in state:
            visit(m, [m])
    return cycles


def test_imports_go_downward_only():
    assert upward_imports(graph()) == []


def test_no_import_cycles():
    assert import_cycles(graph()) == []


def imports_click(path: Path) -> bool:
    tree = ast.parse(path.read_text())
    return any(isinstance(n, ast.Import) and any(a.name.split(".")[0] == "click" for a in n.names)
               or isinstance(n, ast.ImportFrom) and n.level == 0 and (n.module or "").split(".")[0] == "click"
               for n in ast.walk(tree))


def test_only_the_command_line_imports_click():
    """spm_cli/ is the face: the library (and so the benchmarks, which import the library) never needs click."""
    clicky = sorted(m for m, p in module_files().items() if imports_click(p))
    assert clicky and [m for m in clicky if m.split(".")[0] != "spm_cli"] == []


def test_no_module_over_max_lines():
    long = {m: n for m, p in module_files().items() if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert long == {}


def test_the_checks_find_what_they_look_for():
    planted = {"spm_data.io.a": {"spm_data.pipelines.b"}, "spm_data.pipelines.b": {"spm_data.io.a"}}
    assert upward_imports(planted) == ["spm_data.io.a (layer spm_data.io) imports spm_data.pipelines.b "
                                       "(layer spm_data.pipelines)"]
    assert import_cycles(planted) == ["spm_data.io.a -> spm_data.pipelines.b -> spm_data.io.a"]
    assert len(modules()) > 60 and "spm_data.io.shards.reader" in modules() and "cli" in modules()
    assert BACKENDS == {"spm_data.render.pyrender_backend", "spm_data.render.blender"}
    assert REGISTRY == {"spm_data.render", "spm_data.render.blender_settings"}
    assert layer("spm_data.render") < layer("spm_data.core.specs") < layer("spm_data.render.base")


FORBIDDEN = ("bpy", "OpenGL", "pyrender", "pyglet")
# Every module except the renderer backends, which import their libraries when a renderer is built.
CORE = [m for m in modules() if m not in BACKENDS]


def test_core_imports_no_renderer_libraries():
    code = ("import sys\n" + "".join(f"import {m}\n" for m in CORE) +
            f"bad = sorted(m for m in sys.modules if m.split('.')[0] in {FORBIDDEN!r})\n"
            "print(','.join(bad))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == ""


def test_renderer_module_does_import_its_library():
    # The check above can fail: importing a backend really pulls its library in.
    code = ("import sys, spm_data.render.pyrender_backend as b; b._import_pyrender(); "
            "print('OpenGL' in sys.modules)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.stdout.strip() == "True", r.stderr
