"""The package's floor plan, written once: which part may import which.

Every ``import`` in ``shinysim`` (at module level or inside a function: a
lazy import is still a dependency) is read from the source with :mod:`ast`
and checked against :data:`LAYERS`: a part may import only parts of lower
layers, never a part of its own layer or above (a back-edge), and the module
graph has no cycles. Third-party imports are checked against what each part
may use (the reconstruction half never a renderer; ``plot`` only matplotlib,
and only inside functions). ``tests/test_recon_isolation.py`` checks the
same at run time: importing everything outside ``sim`` loads no renderer.
"""

from __future__ import annotations

import ast
import importlib
import importlib.util
import pkgutil
import sys
from pathlib import Path

import shinysim

PACKAGE = Path(shinysim.__file__).parent

#: Layers, lowest first. A part may import the parts of lower layers only;
#: parts within a layer are independent of each other. ``""`` is the
#: package's own ``__init__`` (its ``__version__``), which imports nothing.
LAYERS = (
    ("", "errors"),
    ("_shared", "conventions"),
    ("rig", "objects", "theory"),
    ("evaluate",),  # scoring, against the exact models of the objects, rigs and theory below it
    ("io",),  # the floor of file formats: every reader and writer, above the dataclasses it fills
    ("plot",),
    ("sim", "recon"),
    ("calibrate",),
    ("studies", "datasets"),
    ("cli",),
    ("__main__",),  # python -m shinysim: the command line, nothing else
)
RANK = {part: i for i, layer in enumerate(LAYERS) for part in layer}
#: Lower parts a part may still not import: calibration is reconstruction
#: (real images in, a rig out), so it never reaches the simulator either.
NEVER = {"calibrate": {"sim"}}

#: Third-party packages each part may import (the standard library is free).
THIRD_PARTY = {
    "": set(),
    "_shared": {"numpy"},
    "errors": {"jsonschema"},
    "conventions": {"numpy"},
    "rig": {"numpy", "scipy"},  # scipy: rotation vectors of OpenCV poses (rig.opencv)
    "objects": {"numpy"},
    "theory": {"numpy"},
    "evaluate": {"numpy", "scipy"},
    "io": {"numpy", "OpenEXR", "scipy", "png", "PIL", "tifffile", "skimage", "h5py"},
    "plot": {"numpy", "matplotlib"},
    "recon": {"numpy", "skimage", "scipy"},
    "calibrate": {"numpy", "skimage", "scipy"},
    "sim": {"numpy", "mitsuba", "drjit", "trimesh"},
    "studies": {"numpy", "skimage", "matplotlib"},
    "datasets": {"numpy", "dask", "distributed", "mitsuba", "drjit"},
    "cli": {"tqdm"},
    "__main__": set(),
}
#: Imported only inside the functions that need them (so importing the part does not).
LAZY_ONLY = {"errors": {"jsonschema"}, "io": {"h5py"}, "plot": {"matplotlib"}, "studies": {"matplotlib", "mitsuba", "drjit", "trimesh"},
             "datasets": {"dask", "distributed", "mitsuba", "drjit"}}


def module_name(path: Path) -> str:
    rel = path.relative_to(PACKAGE.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def part_of(module: str) -> str:
    """``shinysim.recon.detect`` -> ``recon``; ``shinysim`` -> ``""``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def imports_of(path: Path):
    """(imported module, is_lazy, line) for every import statement of a file.

    Relative imports are resolved; ``from pkg import name`` counts as an
    import of ``pkg.name`` when that is a module, else of ``pkg``.
    """
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    tree = ast.parse(path.read_text(), filename=str(path))
    lazy_nodes = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            lazy_nodes.update(id(n) for n in ast.walk(node) if n is not node)
    out = []
    for node in ast.walk(tree):
        lazy = id(node) in lazy_nodes
        if isinstance(node, ast.Import):
            out += [(a.name, lazy, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module
            for a in node.names:
                sub = f"{mod}.{a.name}"
                is_module = (PACKAGE.parent / (sub.replace(".", "/") + ".py")).is_file() or (
                    PACKAGE.parent / sub.replace(".", "/") / "__init__.py").is_file()
                out.append((sub if is_module else mod, lazy, node.lineno))
    return out


def package_files():
    return sorted(PACKAGE.rglob("*.py"))


def internal_graph(files=None):
    """{module: {(imported shinysim module, line), ...}} over the package."""
    graph = {}
    for path in files or package_files():
        deps = {(m, line) for m, _, line in imports_of(path) if m.split(".")[0] == "shinysim"}
        graph[module_name(path)] = deps
    return graph


def layering_violations(graph):
    """Back-edges and same-layer edges between parts, as readable lines."""
    bad = []
    for mod, deps in graph.items():
        src = part_of(mod)
        for dep, line in sorted(deps):
            dst = part_of(dep)
            if src == dst:
                continue
            if src not in RANK or dst not in RANK:
                bad.append(f"{mod}:{line} imports {dep}: part {src or dst!r} is not in LAYERS")
            elif dst in NEVER.get(src, ()):
                bad.append(f"{mod}:{line} imports {dep}: {src!r} may never import {dst!r}")
            elif RANK[dst] >= RANK[src]:
                bad.append(f"{mod}:{line} imports {dep}: {src!r} (layer {RANK[src]}) may not import "
                           f"{dst!r} (layer {RANK[dst]})")
    return bad


def cycles(graph):
    """Import cycles among modules (each as a list of module names)."""
    edges = {m: sorted({d for d, _ in deps if d in graph and d != m}) for m, deps in graph.items()}
    # a package's __init__ importing its own submodules is not a cycle back to it
    for m in edges:
        edges[m] = [d for d in edges[m] if not d.startswith(m + ".")]
    found, state = [], {}

    def visit(m, stack):
        state[m] = 1
        stack.append(m)
        for d in edges[m]:
            if state.get(d) == 1:
                found.append(stack[stack.index(d):] + [d])
            elif d not in state:
                visit(d, stack)
        stack.pop()
        state[m] = 2

    for m in sorted(edges):
        if m not in state:
            visit(m, [])
    return found


#: The package's only top-level modules: every other module lives in a part (a package).
TOP_LEVEL = {"__init__", "__main__", "cli", "errors", "conventions", "_shared"}


def test_no_loose_top_level_modules():
    loose = {p.stem for p in PACKAGE.glob("*.py")}
    assert loose == TOP_LEVEL, f"top-level modules besides {sorted(TOP_LEVEL)}: {sorted(loose - TOP_LEVEL)}"


def test_every_part_has_a_layer():
    parts = {part_of(module_name(p)) for p in package_files()}
    assert parts == set(RANK), f"parts without a layer: {parts - set(RANK)}; layers without a part: {set(RANK) - parts}"


def test_no_import_goes_against_the_layers():
    bad = layering_violations(internal_graph())
    assert not bad, "\n".join(bad)


def test_no_import_cycles():
    found = cycles(internal_graph())
    assert not found, "\n".join(" -> ".join(c) for c in found)


def test_the_check_catches_a_back_edge_and_a_cycle():
    """The checks above can fail: a rig that imports a study, and two modules importing each other."""
    graph = internal_graph()
    graph["shinysim.rig"] = graph["shinysim.rig"] | {("shinysim.studies.scan", 1)}
    graph["shinysim.recon.detect"] = graph["shinysim.recon.detect"] | {("shinysim.recon.pipeline", 1)}
    graph["shinysim.theory.mirror"] = graph["shinysim.theory.mirror"] | {("shinysim.evaluate", 1)}
    graph["shinysim.calibrate"] = graph["shinysim.calibrate"] | {("shinysim.sim.render", 1)}
    bad = layering_violations(graph)
    assert any("shinysim.rig:1 imports shinysim.studies.scan" in b for b in bad)
    assert any("'theory' (layer 2) may not import 'evaluate' (layer 3)" in b for b in bad)  # a higher layer
    assert any("'calibrate' may never import 'sim'" in b for b in bad)  # lower, but forbidden
    assert any({"shinysim.recon.detect", "shinysim.recon.pipeline"} <= set(c) for c in cycles(graph))
    # an import inside a function counts as an edge too (run_scan imports the simulator lazily)
    scan_imports = imports_of(PACKAGE / "studies" / "scan.py")
    assert ("shinysim.sim.render", True) in {(m, lazy) for m, lazy, _ in scan_imports}


def test_every_internal_import_names_a_module():
    """A relative import one level short (``from ..sim`` inside a subpackage) names no module: caught here,
    not only when the function holding it runs."""
    def exists(mod):
        path = PACKAGE.parent / mod.replace(".", "/")
        return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()

    bad = [f"{module_name(p)}:{line} imports {dep}" for p in package_files()
           for dep, _, line in imports_of(p) if dep.split(".")[0] == "shinysim" and not exists(dep)]
    assert not bad, "\n".join(bad)


def test_third_party_imports_stay_in_their_parts():
    bad = []
    for path in package_files():
        mod = module_name(path)
        part = part_of(mod)
        for dep, lazy, line in imports_of(path):
            top = dep.split(".")[0]
            if top == "shinysim" or top in sys.stdlib_module_names:
                continue
            if top not in THIRD_PARTY[part]:
                bad.append(f"{mod}:{line} imports {top}, not allowed in {part!r}")
            elif top in LAZY_ONLY.get(part, ()) and not lazy:
                bad.append(f"{mod}:{line} imports {top} at module level; {part!r} imports it inside functions only")
    assert not bad, "\n".join(bad)


def all_modules():
    return sorted(m.name for m in pkgutil.walk_packages(shinysim.__path__, "shinysim."))


def declares_all(path):
    tree = ast.parse(path.read_text())
    return any(isinstance(n, ast.Assign) and any(getattr(t, "id", None) == "__all__" for t in n.targets)
               for n in tree.body)


def test_every_module_declares_its_public_names():
    missing = [module_name(p) for p in package_files() if not declares_all(p)]
    assert not missing, f"modules without __all__: {missing}"
    has_renderer = importlib.util.find_spec("mitsuba") is not None
    modules = all_modules()
    dangling = []
    for name in ["shinysim"] + modules:
        if name.startswith("shinysim.sim.") and not has_renderer:
            continue
        mod = importlib.import_module(name)
        dangling += [f"{name}.{n}" for n in mod.__all__ if not hasattr(mod, n) and f"{name}.{n}" not in modules]
    assert not dangling, f"names in __all__ that do not exist: {dangling}"


def test_lazy_faces_give_every_public_name_of_their_modules():
    """A lazy face lists its modules' names by hand; each list must be its module's ``__all__``, so a name added
    to a module cannot be missing from the face (or a removed one linger there)."""
    has_renderer = importlib.util.find_spec("mitsuba") is not None
    drift = []
    for face in ("shinysim.sim", "shinysim.plot", "shinysim.datasets"):  # (studies' face lists its modules only)
        if face == "shinysim.sim" and not has_renderer:
            continue
        package = importlib.import_module(face)
        assert package.__face__, face
        drift += [f"{face}.{m.name} is not in the face" for m in pkgutil.iter_modules(package.__path__)
                  if not m.name.startswith("_") and m.name not in package.__all__]
        for part, names in package.__face__.items():
            module = importlib.import_module(f"{face}.{part}")
            if set(names) != set(module.__all__):
                drift.append(f"{face}.{part}: face {sorted(set(names) ^ set(module.__all__))}")
            drift += [f"{face}.{n} is not {part}.{n}" for n in names if getattr(package, n) is not getattr(module, n)]
    assert not drift, drift
