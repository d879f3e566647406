"""No stage imports another stage, and no stage file grows past ~300 lines: a stage file reads,
calls and publishes; when it grows past ~300 lines, the core has leaked into it.

A stage (``nsim/stages/<stage>.py``) reads its inputs, calls the core and publishes; what two stages
share lives in the core (``nsim/rendering/``, ``nsim/sensors/``, ...), never in one of the stages.
The check parses the sources with ``ast`` (nothing is imported) and looks at every import statement,
at module level and inside functions and classes alike (a lazy import is still a dependency):
``import nsim.stages.x``, ``from nsim.stages.x import y``, ``from nsim.stages import x`` and their
relative forms (``from . import x``, ``from .x import y``). The package's ``__init__`` (the stage
registry) is held to the same rule: it loads stages by name when asked (``stage_module``), never by
an import statement. The size check counts every line of each ``nsim/stages/*.py``; the stages still
over the limit are listed in ``OVER_LIMIT``, each held to the size it had when listed (it may shrink,
never grow).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: Modules of ``nsim/stages/`` that are no stage: the plumbing every stage shares (the run-cache check, the
#: device in the key, rebuilding, the scene input), which any stage may import.
SHARED = {"runner"}
#: The most lines a stage file may have.
MAX_STAGE_LINES = 300
#: Stage files still over ``MAX_STAGE_LINES`` (issue 23), each with the size it may not exceed.
OVER_LIMIT: dict[str, int] = {}


def stage_import_violations(root: Path, package: str = "nsim.stages") -> list[str]:
    """``"<file>:<line>: imports <package>.<stage>"`` for every import, in a module of ``package``, of one of
    its stage modules other than the importer itself."""
    folder = root.joinpath(*package.split("."))
    stages = {p.stem for p in folder.glob("*.py") if p.name != "__init__.py"} - SHARED
    found = []
    for path in sorted(folder.glob("*.py")):
        me = path.stem
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        imports = [n for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom))]
        for node in sorted(imports, key=lambda n: n.lineno):
            for other in _stages_named(node, package, stages):
                if other != me:
                    found.append(f"{path.relative_to(root).as_posix()}:{node.lineno}: imports {package}.{other}")
    return found


def _stages_named(node: ast.AST, package: str, stages: set[str]) -> list[str]:
    """The stage modules of ``package`` that the statement ``node`` (in a module of ``package``) imports."""
    if isinstance(node, ast.Import):
        names = [alias.name for alias in node.names]
    elif isinstance(node, ast.ImportFrom):
        if node.level:  # relative to the importing module's package, ``package``
            parts = package.split(".")
            base = ".".join(parts[: len(parts) - (node.level - 1)] + ([node.module] if node.module else []))
        else:
            base = node.module or ""
        names = [base] + [f"{base}.{alias.name}" for alias in node.names]
    else:
        return []
    out = []
    for name in names:
        if name.startswith(package + "."):
            stage = name[len(package) + 1 :].split(".")[0]
            if stage in stages and stage not in out:
                out.append(stage)
    return out


def test_no_stage_imports_another_stage():
    stages = {p.stem for p in (ROOT / "nsim" / "stages").glob("*.py")}
    assert {"render", "evaluate", "capture"} <= stages  # the check sees the stages (an empty folder would pass)
    found = stage_import_violations(ROOT)
    assert not found, ("stages import other stages (move what they share into the core):\n" + "\n".join(found))


def test_violations_are_found_and_named(tmp_path):
    pkg = tmp_path / "pkg" / "stages"
    pkg.mkdir(parents=True)
    (tmp_path / "pkg" / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("import importlib\nfrom pkg.stages.beta import B\n")  # a registry that imports
    (pkg / "alpha.py").write_text(
        "import json\n"
        "from pkg.core import helper\n"
        "from pkg.stages import alpha\n"  # itself: not another stage
        "from pkg.stages import registry_name\n"  # a name of the package's __init__, no stage
        "def f():\n"
        "    from pkg.stages.beta import B\n"  # lazy: still a dependency
        "    return B\n"
    )
    (pkg / "beta.py").write_text(
        "B = 1\n"
        "class K:\n"
        "    import pkg.stages.gamma.sub\n"
        "if True:\n"
        "    from . import alpha, gamma\n"
    )
    (pkg / "gamma.py").write_text("from .beta import B\nfrom ..core import helper\n")
    (tmp_path / "pkg" / "core.py").write_text("helper = 1\n")
    assert stage_import_violations(tmp_path, "pkg.stages") == [
        "pkg/stages/__init__.py:2: imports pkg.stages.beta",
        "pkg/stages/alpha.py:6: imports pkg.stages.beta",
        "pkg/stages/beta.py:3: imports pkg.stages.gamma",
        "pkg/stages/beta.py:5: imports pkg.stages.alpha",
        "pkg/stages/beta.py:5: imports pkg.stages.gamma",
        "pkg/stages/gamma.py:1: imports pkg.stages.beta",
    ]


def stage_size_violations(folder: Path, limit: int = MAX_STAGE_LINES,
                          allowed: dict[str, int] | None = None) -> list[str]:
    """``"<file>: N lines (at most M)"`` for every ``*.py`` in ``folder`` longer than ``limit`` lines, or
    than its own entry in ``allowed`` (a file listed there may have that many)."""
    allowed = allowed or {}
    found = []
    for path in sorted(folder.glob("*.py")):
        lines = len(path.read_text(encoding="utf-8").splitlines())
        most = max(limit, allowed.get(path.name, limit))
        if lines > most:
            found.append(f"{path.name}: {lines} lines (at most {most})")
    return found


def test_stage_files_stay_thin():
    folder = ROOT / "nsim" / "stages"
    assert (folder / "reconstruct.py").is_file() and "reconstruct.py" not in OVER_LIMIT
    found = stage_size_violations(folder, MAX_STAGE_LINES, OVER_LIMIT)
    assert not found, ("stage files over the limit (move the core work below the stages):\n" + "\n".join(found))


def test_size_violations_are_found_and_named(tmp_path):
    (tmp_path / "thin.py").write_text("x = 1\n" * 300)
    (tmp_path / "fat.py").write_text("x = 1\n" * 301)
    (tmp_path / "listed.py").write_text("x = 1\n" * 320)
    (tmp_path / "grown.py").write_text("x = 1\n" * 321)
    (tmp_path / "notes.txt").write_text("x = 1\n" * 999)  # not a module
    assert stage_size_violations(tmp_path, 300, {"listed.py": 320, "grown.py": 320}) == [
        "fat.py: 301 lines (at most 300)",
        "grown.py: 321 lines (at most 320)",
    ]
    assert stage_size_violations(tmp_path, 400) == []


def test_every_stage_says_whether_it_repeats_across_cpus():
    """nsim.stages.BIT_STABLE covers every stage once (bench/reproducible.py and tests/data/demo_ids.json use it)."""
    from nsim.stages import BIT_STABLE, STAGE_MODULES

    assert set(BIT_STABLE) == set(STAGE_MODULES)
    assert all(isinstance(v, bool) and why for v, why in BIT_STABLE.values())
