"""nsim's imports form layers: no cycle between its folders, and none between its modules.

Two graphs, both built from the source with ``ast`` (nothing is imported):

- **Every import**, wherever it is written (module level, inside functions, under
  ``if TYPE_CHECKING:``): a lazy import is still a dependency a reader must follow. Between nsim's
  folders (``nsim/rendering`` -> ``nsim/volume``) it must have no cycle: the folders are layers and
  look down only. Between modules it must have no cycle either.
- **Load-time imports** (below): what runs while a module loads, for the traceback a cycle gives.

The load-time graph's edges are the nsim-internal imports that run when a module loads: top-level statements, including those inside
top-level ``if``/``try``/``with``/``for`` blocks and class bodies, but not those under
``if TYPE_CHECKING:`` (never run) or ``if __name__ == "__main__":`` (run as a script only).
Function-level (lazy) imports are **not** edges: they run when the function is called, after the
modules involved have loaded, which is how a module may use one that imports it. (So a cycle
closed by a lazy or a TYPE_CHECKING import passes this test.)

Names are resolved the way Python loads them: relative imports against the importer's package;
``import a.b.c`` loads ``a``, ``a.b`` and ``a.b.c``; ``from a.b import c`` loads ``a.b`` and, when
``c`` is a submodule, ``a.b.c``. A package the importer sits in is already loading (Python runs a
package's ``__init__`` before its modules), so passing through it is no edge; naming it in
``from pkg import name`` for a name its ``__init__`` defines is one.
"""

from __future__ import annotations

import ast
from collections import deque
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

Graph = dict[str, dict[str, int]]
"""module -> {imported module: line of the first import statement that loads it}."""


def module_files(root: Path, package: str) -> dict[str, Path]:
    """Dotted module name -> source file, for every ``.py`` under ``root / package``."""
    out = {}
    for path in sorted((root / package).rglob("*.py")):
        parts = path.relative_to(root).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def _never_on_import(test: ast.expr) -> bool:
    """``if TYPE_CHECKING:`` (type checkers only) and ``if __name__ == "__main__":`` (scripts only)."""
    if isinstance(test, ast.Compare) and isinstance(test.left, ast.Name) and test.left.id == "__name__":
        right = test.comparators[0]
        return isinstance(test.ops[0], ast.Eq) and isinstance(right, ast.Constant) and right.value == "__main__"
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def load_time_imports(body: list[ast.stmt]):
    """The import statements among ``body`` that run when the module loads (not in functions)."""
    try_types = (ast.Try, *((ast.TryStar,) if hasattr(ast, "TryStar") else ()))
    for node in body:
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
        elif isinstance(node, ast.If):
            if not _never_on_import(node.test):
                yield from load_time_imports(node.body)
            yield from load_time_imports(node.orelse)
        elif isinstance(node, try_types):
            for block in (node.body, *(h.body for h in node.handlers), node.orelse, node.finalbody):
                yield from load_time_imports(block)
        elif isinstance(node, (ast.With, ast.For, ast.While)):
            yield from load_time_imports(node.body)
            yield from load_time_imports(getattr(node, "orelse", []))
        elif isinstance(node, ast.ClassDef):
            yield from load_time_imports(node.body)
        # FunctionDef / AsyncFunctionDef: lazy imports, not edges


def _loaded_by(
    node: ast.Import | ast.ImportFrom, module: str, is_package: bool, modules: set[str]
) -> set[str]:
    """The modules of ``modules`` that ``node``, in ``module``, needs while ``module`` loads."""
    reads: set[str] = set()  # packages whose own namespace the statement reads
    if isinstance(node, ast.Import):
        targets = [alias.name for alias in node.names]
    else:
        if node.level:
            parts = (module if is_package else module.rpartition(".")[0]).split(".")
            base = ".".join(parts[: len(parts) - (node.level - 1)] + ([node.module] if node.module else []))
        else:
            base = node.module or ""
        targets = [base]
        for alias in node.names:
            if f"{base}.{alias.name}" in modules:
                targets.append(f"{base}.{alias.name}")
            else:
                reads.add(base)
    loaded = set()
    for name in targets:
        parts = name.split(".")
        loaded.update(".".join(parts[:i]) for i in range(1, len(parts) + 1))
    # a package the importer sits in is already loading: passing through it is no edge
    loaded = {m for m in loaded if not module.startswith(m + ".")}
    return {m for m in loaded | reads if m in modules and m != module}


def every_import(tree: ast.Module):
    """Every import statement of a module, wherever it is written (functions and TYPE_CHECKING included)."""
    return (node for node in ast.walk(tree) if isinstance(node, (ast.Import, ast.ImportFrom)))


def import_graph(root: Path, package: str, lazy: bool = False) -> Graph:
    """module -> the modules it imports: while it loads (``lazy`` false), or anywhere in it (``lazy`` true)."""
    files = module_files(root, package)
    modules = set(files)
    graph: Graph = {}
    for module, path in files.items():
        edges: dict[str, int] = {}
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for node in every_import(tree) if lazy else load_time_imports(tree.body):
            for target in _loaded_by(node, module, path.name == "__init__.py", modules):
                edges.setdefault(target, node.lineno)
        graph[module] = edges
    return graph


def import_cycles(graph: Graph) -> list[list[str]]:
    """One shortest cycle ``[a, b, ..., a]`` per strongly connected component of more than one module."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[set[str]] = []

    def visit(v: str) -> None:  # Tarjan
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, {}):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = set()
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.add(w)
                if w == v:
                    break
            components.append(comp)

    for v in sorted(graph):
        if v not in index:
            visit(v)

    cycles = []
    for comp in components:
        if len(comp) < 2:
            continue
        start = min(comp)
        parent: dict[str, str] = {}
        queue, end = deque([start]), None
        while end is None:  # breadth first inside the component, back to start
            v = queue.popleft()
            for w in sorted(graph[v]):
                if w == start:
                    end = v
                    break
                if w in comp and w not in parent:
                    parent[w] = v
                    queue.append(w)
        path = [end]
        while path[-1] != start:
            path.append(parent[path[-1]])
        cycles.append([*reversed(path), start])
    return sorted(cycles)


def folder_graph(graph: Graph, package: str) -> Graph:
    """The module graph folded onto ``package``'s first-level folders (``nsim.rendering.people`` -> ``rendering``);
    top-level modules (``nsim.cli``, ``nsim.config``) are no folder and drop out."""
    packages = {m for m in graph if any(o.startswith(m + ".") for o in graph)}

    def folder(module: str) -> str | None:
        parts = module.split(".")
        in_folder = len(parts) > 2 or (len(parts) == 2 and module in packages)
        return parts[1] if parts[0] == package and in_folder else None

    folders: Graph = {}
    for module, edges in graph.items():
        src = folder(module)
        if src is None:
            continue
        folders.setdefault(src, {})
        for target, line in edges.items():
            dst = folder(target)
            if dst is not None and dst != src:
                folders[src].setdefault(dst, line)
    return folders


def describe(cycle: list[str], graph: Graph) -> str:
    """``a (line 3) -> b (line 7) -> a``: each module with the line of its import of the next."""
    steps = (f"{a} (line {graph[a][b]})" for a, b in zip(cycle[:-1], cycle[1:], strict=True))
    return " -> ".join(steps) + f" -> {cycle[-1]}"


def test_nsim_has_no_import_cycles():
    graph = import_graph(ROOT, "nsim")
    # the builder sees the imports (an empty graph would pass trivially)
    assert graph["nsim.crowd.social_force"]["nsim.crowd.state"] > 0
    assert "nsim.crowd.state" in graph["nsim.crowd.behaviours"]
    cycles = import_cycles(graph)
    assert not cycles, "import cycles (break them, or make one of the imports lazy):\n" + "\n".join(
        describe(c, graph) for c in cycles
    )


def test_nsim_folders_are_layers_counting_imports_inside_functions():
    graph = import_graph(ROOT, "nsim", lazy=True)
    folders = folder_graph(graph, "nsim")
    # the builder sees lazy imports (crowd/sensors.py imports rendering inside a method) and folds them onto folders
    assert "rendering" in folders["crowd"] and "volume" in folders["rendering"]
    where = {(a, b): f"{a} -> {b}" for a in folders for b in folders[a]}
    cycles = import_cycles(folders)
    assert not cycles, "cycles between nsim's folders (move the shared piece below both):\n" + "\n".join(
        " ; ".join(where[(a, b)] + _first_import(graph, a, b) for a, b in zip(c[:-1], c[1:], strict=True))
        for c in cycles)
    module_cycles = import_cycles(graph)
    assert not module_cycles, "module cycles counting imports inside functions:\n" + "\n".join(
        describe(c, graph) for c in module_cycles)


def _first_import(graph: Graph, a: str, b: str) -> str:
    """`` (nsim.a.x line 3 imports nsim.b.y)``: one import that makes folder ``a`` depend on folder ``b``."""
    for module, edges in sorted(graph.items()):
        for target, line in sorted(edges.items()):
            if module.startswith(f"nsim.{a}.") and target.startswith(f"nsim.{b}"):
                return f" ({module} line {line} imports {target})"
    return ""


def test_folder_graph_counts_lazy_imports_and_finds_folder_cycles(tmp_path):
    _write(tmp_path, {
        "pkg/__init__.py": "",
        "pkg/top.py": "from pkg.low.a import A\n",
        "pkg/low/__init__.py": "",
        "pkg/low/a.py": "A = 1\ndef f():\n    from pkg.high.b import B\n",
        "pkg/high/__init__.py": "",
        "pkg/high/b.py": "from pkg.low.a import A\nB = 2\n",
    })
    assert import_cycles(import_graph(tmp_path, "pkg")) == []  # the load-time graph misses the lazy import
    lazy = import_graph(tmp_path, "pkg", lazy=True)
    folders = folder_graph(lazy, "pkg")
    assert folders == {"low": {"high": 3}, "high": {"low": 1}}  # pkg.top is no folder
    assert import_cycles(folders) == [["high", "low", "high"]]
    (tmp_path / "pkg/low/a.py").write_text("A = 1\n")
    assert import_cycles(folder_graph(import_graph(tmp_path, "pkg", lazy=True), "pkg")) == []


def _write(root: Path, files: dict[str, str]) -> None:
    for rel, text in files.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)


def test_graph_resolves_imports_as_python_loads_them(tmp_path):
    _write(tmp_path, {
        "pkg/__init__.py": "from pkg.a import A\n",
        "pkg/a.py": (
            "from typing import TYPE_CHECKING\n"
            "import os\n"
            "from . import b\n"
            "if TYPE_CHECKING:\n"
            "    from pkg.c import C\n"
            "try:\n"
            "    from .sub import d\n"
            "except ImportError:\n"
            "    d = None\n"
            "def f():\n"
            "    from pkg import c\n"
            "class K:\n"
            "    from pkg.c import C\n"
            "A = 1\n"
        ),
        "pkg/b.py": "import pkg.sub.d as dd\n",
        "pkg/c.py": 'C = 2\nif __name__ == "__main__":\n    import pkg.b\n',
        "pkg/sub/__init__.py": "",
        "pkg/sub/d.py": "from .. import b\nfrom pkg import A\n",
    })
    graph = import_graph(tmp_path, "pkg")
    assert {m: set(e) for m, e in graph.items()} == {
        "pkg": {"pkg.a"},
        # not pkg (its own package, passed through), not pkg.c under TYPE_CHECKING or in f()...
        # ...but pkg.c from the class body, which runs at load time
        "pkg.a": {"pkg.b", "pkg.sub", "pkg.sub.d", "pkg.c"},
        "pkg.b": {"pkg.sub", "pkg.sub.d"},
        "pkg.c": set(),  # its import runs only as a script
        "pkg.sub": set(),
        # relative two levels up; `from pkg import A` reads pkg's own namespace: an edge
        "pkg.sub.d": {"pkg.b", "pkg"},
    }
    assert graph["pkg.a"]["pkg.b"] == 3 and graph["pkg.a"]["pkg.sub.d"] == 7


def test_cycles_are_found_and_named(tmp_path):
    assert import_cycles({"a": {"b": 1}, "b": {"c": 1}, "c": {}, "d": {"b": 1, "c": 2}}) == []
    graph = {"a": {"b": 1}, "b": {"c": 2, "a": 5}, "c": {"a": 3}, "d": {"a": 4}, "e": {"f": 1}, "f": {"e": 9}}
    assert import_cycles(graph) == [["a", "b", "a"], ["e", "f", "e"]]
    assert describe(["a", "b", "a"], graph) == "a (line 1) -> b (line 5) -> a"

    _write(tmp_path, {
        "pkg/__init__.py": "",
        "pkg/x.py": "from pkg.y import Y\nX = 1\n",
        "pkg/y.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from pkg.x import X\nY = 2\n",
    })
    assert import_cycles(import_graph(tmp_path, "pkg")) == []
    (tmp_path / "pkg/y.py").write_text("from pkg import x\nY = 2\n")
    assert import_cycles(import_graph(tmp_path, "pkg")) == [["pkg.x", "pkg.y", "pkg.x"]]
