"""The code's layers: no import cycle between modules, and reporting without the training stack."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("sb3_sgfd", "sgfd_envs", "zoo", "sgfd_analysis")


def top_level_imports(node: ast.AST) -> set[str]:
    """What a module imports when it is imported: not inside functions, not under ``if TYPE_CHECKING``."""
    imported = set()
    for child in ast.iter_child_nodes(node):
        if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            continue
        if isinstance(child, ast.If) and "TYPE_CHECKING" in ast.dump(child.test):
            continue
        if isinstance(child, ast.ImportFrom) and child.module:
            # "from package import submodule" imports the submodule
            imported |= {f"{child.module}.{alias.name}" for alias in child.names} | {child.module}
        elif isinstance(child, ast.Import):
            imported |= {alias.name for alias in child.names}
        imported |= top_level_imports(child)
    return imported


def module_imports() -> dict[str, set[str]]:
    """Module -> the project modules it imports at import time (not inside functions, not for type checking)."""
    graph = {}
    for package in PACKAGES:
        for path in (REPO / package).rglob("*.py"):
            name = ".".join(path.relative_to(REPO).with_suffix("").parts).removesuffix(".__init__")
            graph[name] = top_level_imports(ast.parse(path.read_text()))
    return {name: {dep for dep in deps if dep in graph and dep != name} for name, deps in graph.items()}


def test_no_import_cycle_between_modules():
    graph = module_imports()
    # a package's __init__ importing its own submodules is the package, not a cycle
    edges = {name: {dep for dep in deps if not name.startswith(f"{dep}.")} for name, deps in graph.items()}
    assert len(graph) > 40 and "zoo.runs" in edges["zoo.evaluate"]
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


def test_reporting_imports_neither_torch_nor_rl_zoo3():
    code = "import sys, zoo.cli, zoo.plot, zoo.runs, zoo.statistics, zoo.arguments; "
    code += "print(sorted(m for m in ('torch', 'rl_zoo3', 'optuna', 'ray', 'stable_baselines3') if m in sys.modules))"
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO)
    assert loaded.stdout.strip() == "[]"
