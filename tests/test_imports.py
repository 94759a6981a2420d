"""The import graph of ncs_lite, read from the source with `ast` (module-level imports and
those inside functions alike): no cycle, no import of a higher layer, and a reason beside
every import left inside a function.

The layers, lowest first. A module may import its own layer and the layers below it; a new
module must be given a layer here. Within a layer the graph must still be acyclic.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE_DIR = Path(__file__).resolve().parents[1] / "ncs_lite"

LAYERS = (
    # helpers every stage uses: files, caches, worker processes, sweeps
    ("infrastructure", ("ncs_lite.utils", "ncs_lite.cache", "ncs_lite.tensor_files", "ncs_lite.workers",
                        "ncs_lite.sweeps")),
    # the presets and the choices every stage reads (it imports none of them)
    ("configuration", ("ncs_lite.config",)),
    # the stages' parts: environments, the experience buffer, dSLATE's modules
    ("parts", ("ncs_lite.envs", "ncs_lite.data", "ncs_lite.models")),
    # a trained dSLATE: its checkpoint file and loading it
    ("trained model", ("ncs_lite.inference",)),
    # what learns and acts: NCS, the baselines, training dSLATE
    ("methods", ("ncs_lite.ncs", "ncs_lite.baselines", "ncs_lite.training")),
    # measuring them: the task sets and success, segmentation and factorization measures
    ("measures", ("ncs_lite.evaluation", "ncs_lite.metrics")),
    # the main comparison and the results tables with the docs generated from them
    ("results", ("ncs_lite.experiments.comparison", "ncs_lite.docs", "ncs_lite.experiments.tables",
                 "ncs_lite.experiments")),
    # Appendix D's experiments (Figs. 9-11)
    ("appendix experiments", ("ncs_lite.experiments.stress", "ncs_lite.experiments.hyperparameters")),
    # what a reader runs: the tables, notebooks' figures, the book, exercises, benchmarks
    ("entry points", ("ncs_lite.experiments.reproduce", "ncs_lite.figures", "ncs_lite.book", "ncs_lite.exercises",
                      "ncs_lite.bench")),
    # the command line, and the package itself (its lazy `ncs_lite.load_dslate`)
    ("command line", ("ncs_lite.__main__", "ncs_lite")),
)
REASON = "# local:"        # how an import inside a function says why it is there


# ---------------------------------------------------------------------- reading the graph
def package_modules(root: Path = PACKAGE_DIR) -> dict[str, Path]:
    """{dotted module name: file} of every module of the package (a package by its __init__)."""
    modules = {}
    for path in sorted(root.rglob("*.py")):
        parts = list(path.relative_to(root.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        modules[".".join(parts)] = path
    return modules


def _base(module: str, path: Path, node: ast.ImportFrom) -> str:
    """The absolute module a `from ... import` statement in `module` names."""
    if not node.level:
        return node.module or ""
    package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    base = package[:len(package) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def imported_modules(module: str, path: Path, node: ast.AST, modules) -> set[str]:
    """The package's modules an import statement loads: the one it names and, for `from pkg
    import name`, the submodule `pkg.name` when there is one."""
    if isinstance(node, ast.Import):
        return {a.name for a in node.names if a.name in modules}
    base = _base(module, path, node)
    out = {base} if base in modules else set()
    return out | {f"{base}.{a.name}" for a in node.names if f"{base}.{a.name}" in modules}


def import_graph(modules: dict[str, Path]) -> dict[str, set[str]]:
    """{module: the package's modules it imports}, every import statement counted (at module
    level, under an `if`, or inside a function)."""
    graph = {}
    for module, path in modules.items():
        tree = ast.parse(path.read_text(), str(path))
        targets = set()
        for node in ast.walk(tree):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                targets |= imported_modules(module, path, node, modules)
        graph[module] = targets - {module}
    return graph


# ---------------------------------------------------------------------- the three rules
def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle [a, b, ..., a], or None when the graph is acyclic."""
    state: dict[str, int] = {}          # 1: on the current path, 2: done
    path: list[str] = []

    def visit(node):
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return path[path.index(nxt):] + [nxt]
            if nxt not in state:
                found = visit(nxt)
                if found:
                    return found
        state[node] = 2
        path.pop()
        return None

    for node in sorted(graph):
        if node not in state:
            found = visit(node)
            if found:
                return found
    return None


def layer_of(module: str, layers=LAYERS) -> int | None:
    """The index of `module`'s layer: the layer naming it or its nearest parent package."""
    best, depth = None, -1
    for index, (_, prefixes) in enumerate(layers):
        for prefix in prefixes:
            if (module == prefix or module.startswith(prefix + ".")) and prefix.count(".") > depth:
                best, depth = index, prefix.count(".")
    return best


def upward_imports(graph: dict[str, set[str]], layers=LAYERS) -> list[str]:
    """Every import of a module in a higher layer than the importer's, as 'a (layer) -> b (layer)'."""
    out = []
    for module, targets in sorted(graph.items()):
        for target in sorted(targets):
            low, high = layer_of(module, layers), layer_of(target, layers)
            if high > low:
                out.append(f"{module} ({layers[low][0]}) -> {target} ({layers[high][0]})")
    return out


def unexplained_local_imports(source: str, where: str = "<source>") -> list[str]:
    """Imports inside a function (and `importlib.import_module` calls, which hide an import)
    without a `# local: why` comment on their line or the line above (or above the run of
    imports they end), as 'where:line: code'."""
    tree = ast.parse(source)
    lines = source.splitlines()
    found, explained_lines = [], set()

    def explained(node) -> bool:
        lineno = node.lineno
        above = lines[lineno - 2].strip() if lineno > 1 else ""
        ok = (REASON in lines[lineno - 1] or (above.startswith("#") and REASON in above)
              or (isinstance(node, (ast.Import, ast.ImportFrom)) and lineno - 1 in explained_lines))
        if ok:
            explained_lines.add(node.end_lineno)
        return ok

    def walk(node, in_function: bool):
        for child in ast.iter_child_nodes(node):
            inside = in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            hidden = (isinstance(child, ast.Call) and isinstance(child.func, ast.Attribute)
                      and child.func.attr == "import_module")
            if ((in_function and isinstance(child, (ast.Import, ast.ImportFrom))) or hidden) \
                    and not explained(child):
                found.append(f"{where}:{child.lineno}: {lines[child.lineno - 1].strip()}")
            walk(child, inside)

    walk(tree, False)
    return found


# ---------------------------------------------------------------------- the package
@pytest.fixture(scope="module")
def graph():
    return import_graph(package_modules())


def test_every_module_has_a_layer():
    unplaced = [m for m in package_modules() if layer_of(m) is None]
    assert unplaced == [], f"give these modules a layer in tests/test_imports.py: {unplaced}"


def test_no_import_cycle(graph):
    cycle = find_cycle(graph)
    assert not cycle, f"import cycle: {' -> '.join(cycle or ())}"


def test_no_import_of_a_higher_layer(graph):
    assert upward_imports(graph) == []


def test_every_import_inside_a_function_says_why():
    bad = [line for module, path in package_modules().items()
           for line in unexplained_local_imports(path.read_text(), str(path.relative_to(PACKAGE_DIR.parent)))]
    assert bad == [], "move these imports to the module's top, or add a `# local: why` comment:\n" + "\n".join(bad)


def test_inference_reads_models_without_the_trainer(graph):
    assert "ncs_lite.training" not in graph["ncs_lite.inference"]
    assert "ncs_lite.models.transformer" in graph["ncs_lite.models.decoder"] & graph["ncs_lite.models.dynamics"]


# ---------------------------------------------------------------------- the rules can fail
def test_a_cycle_is_found():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"a"}}) == ["a", "a"]
    assert find_cycle({"a": {"b", "c"}, "b": {"c"}, "c": set()}) is None      # a diamond is no cycle


def test_an_upward_import_is_found():
    layers = (("low", ("p.low",)), ("high", ("p.high", "p")))
    assert layer_of("p.low.sub", layers) == 0 and layer_of("p.other", layers) == 1
    assert upward_imports({"p.low.sub": {"p.high"}, "p.high": {"p.low"}}, layers) == ["p.low.sub (low) -> p.high (high)"]


def test_an_unexplained_local_import_is_found():
    source = ("import os\n"
              "def f():\n"
              "    import torch\n"
              "    # local: optional extra, and what it needs\n"
              "    import submitit\n"
              "    import cloudpickle\n"
              "\n"
              "    import mujoco\n"
              "    from . import x  # local: a reason\n"
              "    return importlib.import_module(name)\n")
    assert unexplained_local_imports(source, "m.py") == ["m.py:3: import torch", "m.py:8: import mujoco",
                                                         "m.py:10: return importlib.import_module(name)"]


def test_the_graph_reads_relative_and_local_imports(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from .sub import b\n")
    (pkg / "sub" / "__init__.py").write_text("from . import b\n")
    (pkg / "sub" / "b.py").write_text("def f():\n    from ..a import x  # local: why\n")
    graph = import_graph(package_modules(pkg))
    assert graph == {"pkg": set(), "pkg.a": {"pkg.sub", "pkg.sub.b"}, "pkg.sub": {"pkg.sub.b"}, "pkg.sub.b": {"pkg.a"}}
    cycle = find_cycle(graph)
    assert cycle[0] == cycle[-1] == "pkg.a" and "pkg.sub.b" in cycle


def test_per_environment_defaults_live_in_config_alone():
    """Every table keyed by environment (`*_BY_ENV`, `ENV_OVERRIDES`) is defined in config.py,
    so a new environment's defaults are added in one place."""
    defined = {}
    for module, path in package_modules().items():
        for node in ast.parse(path.read_text()).body:
            targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AnnAssign) else []
            for t in targets:
                if isinstance(t, ast.Name) and (t.id.endswith("_BY_ENV") or t.id == "ENV_OVERRIDES"):
                    defined.setdefault(t.id, []).append(module)
    assert defined and all(where == ["ncs_lite.config"] for where in defined.values()), defined
