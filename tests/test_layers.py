"""The package's layers (docs/architecture.md), read from its own imports with ``ast``:
every import counts, inside functions too (a lazy import that breaks a circle is still
a circle). A module imports only from its own layer or the layers below it, and the
imports make no circle."""

import ast
import subprocess
import sys
from pathlib import Path

import facesim

PACKAGE = Path(facesim.__file__).resolve().parent

#: Lowest first. The base (configuration, errors, the cache, files, schemas, geometry,
#: worker pools) is imported by all; each subpackage by the ones above it.
LAYERS = ["base", "physics", "face", "speech", "animation", "renderer", "export", "capture", "app"]
BASE = {"config", "errors", "cache", "files", "schema", "geometry", "workers", "timings"}
APP = {"cli", "batch", "dataset", "__main__", ""}
#: The physics' Numba force terms: nothing outside the physics runs them.
KERNELS = {"layout", "numerics", "springs", "repulsion", "bending", "tissue", "damping", "muscle_forces", "rig_control",
           "contacts", "checks", "solver"}


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def layer(module: str) -> str:
    top = module.split(".")[0]
    if top in BASE:
        return "base"
    if top in APP:
        return "app"
    assert top in LAYERS, f"facesim.{module}: in no layer (tests/test_layers.py, docs/architecture.md)"
    return top


def imports() -> dict[str, set[str]]:
    """Each module of facesim (dotted, without 'facesim.') and the facesim modules it imports."""
    found = {}
    modules = {module_name(p) for p in PACKAGE.rglob("*.py")}
    for path in PACKAGE.rglob("*.py"):
        name = module_name(path)
        package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
        if name == "":
            package = []
        targets = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package[: len(package) - node.level + 1]
                    target = base + (node.module.split(".") if node.module else [])
                elif node.module and node.module.split(".")[0] == "facesim":
                    target = node.module.split(".")[1:]
                else:
                    continue
                for alias in node.names:  # `from . import springs` imports a module
                    sub = ".".join(target + [alias.name])
                    targets.add(sub if sub in modules else ".".join(target))
            elif isinstance(node, ast.Import):
                targets |= {a.name.split(".", 1)[1] for a in node.names if a.name.startswith("facesim.")}
        found[name] = {t for t in targets if t != name}
    return found


def test_every_import_goes_down_the_layers_or_stays_in_its_own():
    upward = [f"facesim.{m} ({layer(m)}) imports facesim.{t} ({layer(t)})"
              for m, targets in imports().items() for t in targets if m and t
              and LAYERS.index(layer(t)) > LAYERS.index(layer(m))]
    assert not upward, "\n".join(sorted(upward))


def test_no_module_outside_the_physics_imports_its_kernels():
    reaching = [f"facesim.{m} imports facesim.{t}" for m, targets in imports().items() for t in targets
                if t.startswith("physics.") and t.split(".")[1] in KERNELS and layer(m) != "physics"]
    assert not reaching, "\n".join(sorted(reaching))


def test_the_imports_make_no_circle():
    graph = imports()
    circles, state = [], {}

    def visit(node, path):
        state[node] = "open"
        for target in sorted(graph.get(node, ())):
            if state.get(target) == "open":
                circles.append(" -> ".join(path[path.index(target):] + [target]))
            elif target not in state:
                visit(target, path + [target])
        state[node] = "done"

    for module in sorted(graph):
        if module not in state:
            visit(module, [module])
    assert not circles, "\n".join(circles)


def test_the_layer_rules_catch_an_upward_import_and_a_circle(monkeypatch):
    """The checks above on a graph made to break them: they can fail."""
    import test_layers

    broken = {"physics.model": {"renderer.scene"}, "renderer.scene": {"physics.springs"}, "face.head": {"face.align"},
              "face.align": {"face.head"}}
    monkeypatch.setattr(test_layers, "imports", lambda: broken)
    for check in (test_every_import_goes_down_the_layers_or_stays_in_its_own,
                  test_no_module_outside_the_physics_imports_its_kernels, test_the_imports_make_no_circle):
        try:
            check()
        except AssertionError:
            continue
        raise AssertionError(f"{check.__name__} passed a broken graph")


def test_the_physics_imports_no_renderer_schema_or_command_line():
    """`import facesim.physics` (every module of it) loads none of pyrender, OpenGL,
    pydantic, typer, matplotlib, trimesh or imageio: the simulation runs without them.
    (PyYAML it may: Numba reads its own configuration file with it.)"""
    code = ("import sys, pkgutil, importlib, facesim.physics as p\n"
            "for m in pkgutil.walk_packages(p.__path__, 'facesim.physics.'): importlib.import_module(m.name)\n"
            "print(' '.join(sorted({n.split('.')[0] for n in sys.modules})))")
    loaded = set(subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout.split())
    assert "facesim" in loaded and "numba" in loaded
    assert not loaded & {"pyrender", "OpenGL", "pydantic", "typer", "matplotlib", "trimesh", "imageio"}
