"""How the modules depend on each other: the pipeline's imports run one way
(run -> executors -> worker -> stages), no module reaches into another's private
(underscore) names, and the mesh code and the mesh file readers do not import each
other for an error class. Read from the source with ``ast``, nothing is imported."""
import ast
import os

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PACKAGE = os.path.join(ROOT, "glsynth")


def _module_name(path):
    rel = os.path.relpath(path, ROOT)[:-3].replace(os.sep, ".")
    return rel[:-len(".__init__")] if rel.endswith(".__init__") else rel


def _modules(folder=PACKAGE):
    for root, _, names in os.walk(folder):
        for n in sorted(names):
            if n.endswith(".py"):
                yield _module_name(os.path.join(root, n)), os.path.join(root, n)


def _absolute(module, level, name, is_package):
    """The absolute module of a ``from <dots><name> import`` in ``module``."""
    if level == 0:
        return name
    parts = module.split(".")
    base = parts if is_package else parts[:-1]
    base = base[:len(base) - (level - 1)]
    return ".".join(base + ([name] if name else []))


def _imports(module, path):
    """(imported module, imported name or None, alias) of every glsynth import."""
    tree = ast.parse(open(path, encoding="utf-8").read())
    is_package = path.endswith("__init__.py")
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            src = _absolute(module, node.level, node.module, is_package)
            for a in node.names:
                yield src, a.name, a.asname or a.name
        elif isinstance(node, ast.Import):
            for a in node.names:
                yield a.name, None, a.asname or a.name.split(".")[0]


def _glsynth_deps(module, path):
    """The glsynth modules ``module`` imports (a ``from pkg import mod`` counts as mod)."""
    deps = set()
    for src, name, _ in _imports(module, path):
        if not src.startswith("glsynth"):
            continue
        candidate = f"{src}.{name}" if name else None
        if candidate and os.path.exists(os.path.join(ROOT, *candidate.split(".")) + ".py"):
            deps.add(candidate)
        else:
            deps.add(src)
    return deps


MODULES = dict(_modules())


def _private_uses(module, path):
    """The private names of other glsynth modules that ``module`` imports or uses."""
    private = [f"{src}.{name}" for src, name, _ in _imports(module, path)
               if src.startswith("glsynth") and name and name.startswith("_")
               and not name.startswith("__")]
    # module aliases (``from . import views as V``) used for a private attribute
    aliases = {alias for src, name, alias in _imports(module, path)
               if src.startswith("glsynth") and (name is None or f"{src}.{name}" in MODULES)}
    tree = ast.parse(open(path, encoding="utf-8").read())
    private += [f"{n.value.id}.{n.attr}" for n in ast.walk(tree)
                if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name)
                and n.value.id in aliases and n.attr.startswith("_") and not n.attr.startswith("__")]
    return private


@pytest.mark.parametrize("module", sorted(MODULES))
def test_no_private_names_cross_modules(module):
    private = _private_uses(module, MODULES[module])
    assert private == [], f"{module} uses private names of other modules: {private}"


P = "glsynth.pipeline."
# who may not import whom: the arrows run run -> executors -> worker -> stages
FORBIDDEN = {
    "stages": ("run", "worker", "local_executor", "ray_executor"),
    "worker": ("run", "local_executor", "ray_executor"),
    "local_executor": ("run", "ray_executor"),
    "ray_executor": ("run", "stages", "local_executor"),
    "writer": ("run", "worker", "stages", "local_executor", "ray_executor"),
    "prefetch": ("run", "worker", "stages", "local_executor", "ray_executor"),
}


@pytest.mark.parametrize("module,forbidden", sorted(FORBIDDEN.items()))
def test_pipeline_imports_run_one_way(module, forbidden):
    deps = _glsynth_deps(P + module, MODULES[P + module])
    assert not deps & {P + f for f in forbidden}, deps & {P + f for f in forbidden}


def test_mesh_and_mesh_files_import_one_way():
    assert "glsynth.mesh" not in _glsynth_deps("glsynth.io.meshfile", MODULES["glsynth.io.meshfile"])
    from glsynth import MeshError, errors, mesh
    assert mesh.MeshError is errors.MeshError is MeshError


def test_the_layout_checks_see_imports(tmp_path):
    """The checks above would pass on a parser that saw nothing: they must see these."""
    deps = _glsynth_deps(P + "worker", MODULES[P + "worker"])
    assert {P + "stages", "glsynth.config"} <= deps
    assert P + "worker" in _glsynth_deps(P + "ray_executor", MODULES[P + "ray_executor"])
    bad = tmp_path / "bad.py"
    bad.write_text("from .stages import _Stage\nfrom . import views as V\nV._hidden\n")
    assert _private_uses(P + "bad", str(bad)) == [P + "stages._Stage", "V._hidden"]
