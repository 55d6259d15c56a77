"""The code's layers: no import cycle between modules, and reporting without the training stack."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ("sb3_sgfd", "sgfd_envs", "sgfd_zoo", "sgfd_analysis")


def all_imports(node: ast.AST) -> set[str]:
    """Everything a module imports: at import time, inside functions (lazily) and for type checking alike, since
    each is a dependency of the module on the other."""
    imported = set()
    for child in ast.walk(node):
        if isinstance(child, ast.ImportFrom) and child.module:
            # "from package import submodule" imports the submodule
            imported |= {f"{child.module}.{alias.name}" for alias in child.names} | {child.module}
        elif isinstance(child, ast.Import):
            imported |= {alias.name for alias in child.names}
    return imported


def module_imports() -> dict[str, set[str]]:
    """Module -> the project modules it imports, wherever in it (see ``all_imports``)."""
    graph = {}
    for package in PACKAGES:
        for path in (REPO / package).rglob("*.py"):
            name = ".".join(path.relative_to(REPO).with_suffix("").parts).removesuffix(".__init__")
            graph[name] = all_imports(ast.parse(path.read_text()))
    return {name: {dep for dep in deps if dep in graph and dep != name} for name, deps in graph.items()}


def test_the_import_graph_counts_lazy_and_type_only_imports():
    code = "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import a.b\ndef f():\n    from c import d\n"
    assert {"a.b", "c", "c.d"} <= all_imports(ast.parse(code))
    # the objectives see the algorithm through a Protocol: no edge back to the training loop
    graph = module_imports()
    assert "sb3_sgfd.common.representation" in graph["sb3_sgfd.common.encoder_sac"]
    assert "sb3_sgfd.common.encoder_sac" not in graph["sb3_sgfd.common.representation"]


def test_no_import_cycle_between_modules():
    graph = module_imports()
    # a package's __init__ importing its own submodules is the package, not a cycle
    edges = {name: {dep for dep in deps if not name.startswith(f"{dep}.")} for name, deps in graph.items()}
    assert len(graph) > 40 and "sgfd_zoo.runs.folders" in edges["sgfd_zoo.report.evaluate"]
    cycles = []

    def visit(name: str, path: list[str]) -> None:
        for dep in edges[name]:
            if dep in path:
                cycles.append([*path[path.index(dep) :], dep])
            elif dep not in seen:
                seen.add(dep)
                visit(dep, [*path, dep])

    for start in edges:
        seen = {start}
        visit(start, [start])
    assert not cycles, cycles[:3]


#: what ``sgfd-zoo plot``, ``-h`` and the sweep's planning load: the command, the plots, the run folders and records,
#: the statistics, the argument checks, the files, checkpoints and locks, the plan
REPORTING = [
    "sgfd_zoo.cli",
    "sgfd_zoo.report.plot",
    "sgfd_zoo.runs.folders",
    "sgfd_zoo.runs.records",
    "sgfd_zoo.report.statistics",
    "sgfd_zoo.arguments",
    "sgfd_zoo.runs.files",
    "sgfd_zoo.runs.checkpoints",
    "sgfd_zoo.runs.locks",
    "sgfd_zoo.sweep.plan",
]


def test_reporting_imports_neither_torch_nor_rl_zoo3():
    code = f"import sys, {', '.join(REPORTING)}; "
    code += "print(sorted(m for m in ('torch', 'rl_zoo3', 'optuna', 'ray', 'stable_baselines3') if m in sys.modules))"
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO)
    assert loaded.stdout.strip() == "[]"
