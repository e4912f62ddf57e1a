"""The package as installed and as layered: pyproject.toml lists every package of mrsph/
(so that ``pip install .`` ships all of it, the scenes included), the ``mrsph`` command
is the command line's ``main``, and the import graph runs downwards only: no module
imports one of a higher layer, and there is no circle."""

import ast
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
PACKAGE = REPO / "mrsph"

# The layers, lowest first: a module may import its own layer's modules and lower ones.
# The package's __init__ (the lazy public API) and entry points (__main__) stand above all.
LAYERS = [
    ("limits", "kernel_build", "runtime"),
    ("sph",),
    ("pressure",),
    ("multires",),
    ("scene",),
    ("io",),
    ("simulation", "report", "state"),
    ("app",),
    ("cli",),
]


def _layer(module: str) -> int | None:
    """The layer of ``mrsph.x.y`` by its first component ``x``; None for mrsph itself."""
    parts = module.split(".")
    if parts[0] != "mrsph" or len(parts) < 2:
        return None
    for rank, names in enumerate(LAYERS):
        if parts[1] in names:
            return rank
    raise AssertionError(f"{module}: in no layer of tests/test_packaging.py's LAYERS")


def _module_name(path: Path) -> str:
    rel = path.relative_to(REPO).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _imports(path: Path) -> set[str]:
    """The mrsph modules ``path`` imports, at any depth of its code (lazy imports too)."""
    module = _module_name(path)
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package if node.level else ""
            mod = ".".join(p for p in (base, node.module) if p)
            subs = {f"{mod}.{a.name}" for a in node.names}
            subs = {
                m
                for m in subs
                if (REPO / Path(*m.split("."))).with_suffix(".py").exists()
                or (REPO / Path(*m.split(".")) / "__init__.py").exists()
            }
            # from . import bench imports the module bench; from .x import y the module x
            found.update(subs or {mod})
    return {m for m in found if m == "mrsph" or m.startswith("mrsph.")}


def _sources():
    return sorted(p for p in PACKAGE.rglob("*.py") if "__pycache__" not in p.parts)


def test_pyproject_lists_every_package():
    project = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))
    listed = set(project["tool"]["setuptools"]["packages"])
    folders = {_module_name(p) for p in PACKAGE.rglob("__init__.py")}
    assert listed - {"mrsph.scenes"} == folders, (
        f"pyproject.toml's packages differ from mrsph/'s: missing {sorted(folders - listed)}, "
        f"extra {sorted(listed - folders - {'mrsph.scenes'})}"
    )
    assert project["tool"]["setuptools"]["package-dir"]["mrsph.scenes"] == "scenes"
    assert project["project"]["scripts"]["mrsph"] == "mrsph.cli:main"
    from mrsph.cli import main

    assert callable(main)


def test_the_package_version_is_pyproject_s():
    import mrsph

    version = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["version"]
    assert mrsph.__version__ == version, f"mrsph.__version__ {mrsph.__version__}, pyproject.toml {version}"


def test_imports_run_downwards_only():
    upward = []
    for path in _sources():
        module = _module_name(path)
        if path.name == "__main__.py" or module == "mrsph":
            continue  # entry points and the public API sit on top
        own = _layer(module)
        for target in _imports(path):
            rank = _layer(target)
            if rank is not None and rank > own:
                upward.append(f"{module} (layer {own}) imports {target} (layer {rank})")
    assert not upward, "imports that run up the layers:\n" + "\n".join(upward)


def test_no_import_circle():
    graph = {_module_name(p): {t for t in _imports(p) if t != _module_name(p)} for p in _sources()}
    # a package's __init__ is imported with any of its modules; what it imports is what
    # importing the package imports
    state, circle = {}, []

    def visit(node, path):
        state[node] = 1
        for nxt in sorted(graph.get(node, ())):
            if nxt not in graph or nxt == "mrsph":
                continue
            if state.get(nxt) == 1:
                circle.append(" -> ".join(path[path.index(nxt) :] + [nxt]) if nxt in path else f"{node} -> {nxt}")
            elif nxt not in state:
                visit(nxt, path + [nxt])
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])
    assert not circle, "import circles:\n" + "\n".join(circle)
