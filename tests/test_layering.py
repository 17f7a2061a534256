"""Imports go one way, folder by folder: core, formats -> rendering -> model, data -> editing -> analysis ->
training, bench -> policy -> cli; the viewer on top: viewer/gl (what talks to OpenGL) -> the viewer's app, ui and
tools -> viewer/bench.

A module's layer is its folder (``LAYERS`` below). A module may import its own layer and the layers under it,
never one above; a module outside every listed folder fails; and the import graph between modules has no cycle,
counting imports inside functions too (a lazy import is still an import).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("particlesplat", "viewer")

# lowest first: a module's layer is the folder it lives in (the longest listed package prefix); a module in no
# listed folder has no layer and fails the test
LAYERS: list[tuple[str, tuple[str, ...]]] = [
    ("core, formats", ("particlesplat.core", "particlesplat.formats")),
    ("rendering", ("particlesplat.rendering",)),
    ("model, data", ("particlesplat.model", "particlesplat.data")),
    ("editing", ("particlesplat.editing",)),
    ("analysis", ("particlesplat.analysis",)),
    ("training, bench", ("particlesplat.training", "particlesplat.bench")),
    ("policy", ("particlesplat.policy",)),
    ("cli", ("particlesplat.cli",)),
    # the viewer: its root modules (app, session, state...), ui/ and tools/ import each other, so they are one layer
    ("viewer gl", ("viewer.gl",)),
    ("viewer", ("viewer", "viewer.ui", "viewer.tools")),
    ("viewer bench", ("viewer.bench",)),
]
# the package roots re-export a few core and rendering names lazily; importing them is importing those names
PACKAGE_ROOT_LAYER = {"particlesplat": "rendering"}


def module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def all_modules() -> dict[str, Path]:
    mods = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            mods[module_name(path)] = path
    return mods


def imports_of(name: str, path: Path, known: set[str]) -> set[str]:
    """Modules of ours that ``name`` imports anywhere in its file (module level or inside functions)."""
    is_pkg = path.name == "__init__.py"
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".") if is_pkg else name.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            targets = [mod] + [f"{mod}.{a.name}" for a in node.names]
        for t in targets:
            while t and t not in known:  # the longest prefix that is one of our modules
                t = t.rpartition(".")[0]
            if t and t != name:
                found.add(t)
    return found


def layer_of(name: str) -> int:
    if name in PACKAGE_ROOT_LAYER:
        return [n for n, _ in LAYERS].index(PACKAGE_ROOT_LAYER[name])
    best, best_len = -1, -1
    for i, (_, prefixes) in enumerate(LAYERS):
        for p in prefixes:
            if (name == p or name.startswith(p + ".")) and len(p) > best_len:
                best, best_len = i, len(p)
    return best


def graph() -> dict[str, set[str]]:
    mods = all_modules()
    return {name: imports_of(name, path, set(mods)) for name, path in mods.items()}


def test_every_module_has_a_layer():
    missing = [m for m in all_modules() if layer_of(m) < 0]
    assert not missing, f"give these modules a layer in tests/test_layering.py: {missing}"


def test_every_viewer_folder_is_listed():
    """The viewer's root is a layer of its own modules, so a new folder under viewer/ would join that layer without
    anyone deciding it: each folder is listed by name, and the viewer's layers are ordered gl, the rest, bench."""
    listed = {p for _, prefixes in LAYERS for p in prefixes}
    folders = {f"viewer.{d.name}" for d in (ROOT / "viewer").iterdir() if (d / "__init__.py").is_file()}
    assert folders, "no folder under viewer/"
    assert not folders - listed, f"give these folders a layer in tests/test_layering.py: {sorted(folders - listed)}"
    assert layer_of("particlesplat.cli.main") < layer_of("viewer.gl.renderer")
    assert layer_of("viewer.gl.renderer") < layer_of("viewer.ui.panel") == layer_of("viewer.app")
    assert layer_of("viewer.app") == layer_of("viewer.tools.object_tools") < layer_of("viewer.bench.run")


def test_no_upward_imports():
    names = [n for n, _ in LAYERS]
    bad = []
    for mod, deps in graph().items():
        for dep in deps:
            if dep.split(".")[0] == "viewer" and mod.split(".")[0] == "particlesplat":
                bad.append(f"{mod} imports the viewer ({dep})")
            elif layer_of(dep) > layer_of(mod) and not mod.startswith(dep + "."):
                bad.append(f"{mod} ({names[layer_of(mod)]}) imports {dep} ({names[layer_of(dep)]})")
    assert not bad, "upward imports:\n" + "\n".join(sorted(bad))


def test_library_never_imports_gui_packages():
    gui = ("moderngl", "glfw", "imgui_bundle", "viewer")
    bad = []
    for name, path in all_modules().items():
        if not name.startswith("particlesplat"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            mods = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else [node.module or ""]
                if isinstance(node, ast.ImportFrom) and not node.level
                else []
            )
            bad += [f"{name} imports {m}" for m in mods if m.split(".")[0] in gui]
    assert not bad, bad


def test_no_import_cycles():
    g = graph()
    # a package's __init__ importing its own submodules is how packages work, not a cycle
    edges = {
        m: {d for d in deps if not (d.startswith(m + ".") and all_modules()[m].name == "__init__.py")}
        for m, deps in g.items()
    }
    state: dict[str, int] = {}
    stack: list[str] = []
    cycles: list[list[str]] = []

    def visit(m: str) -> None:
        state[m] = 1
        stack.append(m)
        for d in sorted(edges.get(m, ())):
            if state.get(d) == 1:
                cycles.append(stack[stack.index(d) :] + [d])
            elif d not in state:
                visit(d)
        stack.pop()
        state[m] = 2

    for m in sorted(edges):
        if m not in state:
            visit(m)
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles)


def test_the_checker_sees_a_lazy_upward_import(tmp_path):
    """The test itself: an import inside a function is found and resolved relative to its package."""
    pkg = tmp_path / "particlesplat" / "core"
    pkg.mkdir(parents=True)
    (pkg / "camera.py").write_text("def f():\n    from ..training.trainer import x\n")
    known = {"particlesplat.training.trainer", "particlesplat.core.camera"}
    found = imports_of("particlesplat.core.camera", pkg / "camera.py", known)
    assert found == {"particlesplat.training.trainer"}
    assert layer_of("particlesplat.training.trainer") > layer_of("particlesplat.core.camera")


def test_a_module_outside_the_layer_folders_has_no_layer():
    """A loose module at the package root (or in a folder no layer lists) is refused, not given a layer silently."""
    assert layer_of("particlesplat.helpers") < 0
    assert layer_of("particlesplat.newfolder.thing") < 0
    assert layer_of("particlesplat.core.camera") == 0


def test_package_inits_are_lazy():
    """Importing the edit-file module loads neither the model's networks nor the renderer."""
    import subprocess
    import sys

    code = (
        "import sys, particlesplat.editing.particle_edits\n"
        "heavy = ('particlesplat.rendering.api', 'particlesplat.model.encoder', 'particlesplat.data.dataset')\n"
        "print(','.join(m for m in heavy if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == ""
    code = "import particlesplat as p, particlesplat.model as m, particlesplat.data as d\n"
    code += "print(p.render, m.load_model, d.load_scene)"
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).returncode == 0
