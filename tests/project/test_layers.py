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
    assert len(graph) > 40 and "sgfd_zoo.runs" in edges["sgfd_zoo.evaluate"]
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
    code = "import sys, sgfd_zoo.cli, sgfd_zoo.plot, sgfd_zoo.runs, sgfd_zoo.records, sgfd_zoo.statistics, "
    code += "sgfd_zoo.arguments, sgfd_zoo.files, sgfd_zoo.checkpoints, sgfd_zoo.locks, sgfd_zoo.sweep_plan; "
    code += "print(sorted(m for m in ('torch', 'rl_zoo3', 'optuna', 'ray', 'stable_baselines3') if m in sys.modules))"
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO)
    assert loaded.stdout.strip() == "[]"


ALGORITHMS = ("sgfd", "ambs", "dbc", "ted", "sgqn")


def code_names(tree: ast.AST) -> set[str]:
    """The identifiers and the strings a module's code holds (its docstrings aside): what it can reach things by."""
    docstrings = {
        id(node.body[0].value)
        for node in ast.walk(tree)
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
        and node.body
        and isinstance(node.body[0], ast.Expr)
        and isinstance(node.body[0].value, ast.Constant)
    }
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Name):
            names.add(node.id)
        elif isinstance(node, ast.Attribute):
            names.add(node.attr)
        elif isinstance(node, ast.alias):
            names |= {node.name, node.asname or node.name}
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings:
            names.add(node.value)
    return names


def top_level_names(folder: Path) -> set[str]:
    """The functions, classes and variables the modules under ``folder`` define at their top level (dunders aside)."""
    names = set()
    for path in folder.rglob("*.py"):
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
                names.add(node.name)
            targets = node.targets if isinstance(node, ast.Assign) else [getattr(node, "target", None)]
            names |= {target.id for target in targets if isinstance(target, ast.Name)}
    return {name for name in names if not name.startswith("__")}


def test_common_knows_no_algorithm():
    """sb3_sgfd.common is what the algorithms share: it imports none of them (not even lazily) and its code names
    none of their modules or of what they define, so that an algorithm's folder can be copied or removed alone."""
    graph = module_imports()
    common = {name for name in graph if name == "sb3_sgfd.common" or name.startswith("sb3_sgfd.common.")}
    assert "sb3_sgfd.common.validation" in common and "sb3_sgfd.common.buffers" in common
    folders = [f"sb3_sgfd.{algorithm}" for algorithm in ALGORITHMS]
    imports = sorted(
        f"{name} imports {dep}"
        for name in common
        for dep in graph[name]
        if any(dep == folder or dep.startswith(f"{folder}.") for folder in folders)
    )
    assert not imports, imports
    # What the algorithms' modules define at their top level, less what common defines too
    defined = {folder: top_level_names(REPO / "sb3_sgfd" / folder) for folder in ("common", *ALGORITHMS)}
    algorithm_names = set().union(*(defined[folder] for folder in ALGORITHMS)) - defined["common"]
    assert {"SGFD_SAC", "AMBSPolicy", "check_weights", "attribution_loss"} <= algorithm_names
    named = []
    for path in sorted((REPO / "sb3_sgfd" / "common").rglob("*.py")):
        names = code_names(ast.parse(path.read_text()))
        modules = {name for name in names if any(f"{folder}." in f"{name}." for folder in folders)}
        named += [f"{path.relative_to(REPO)}: {name}" for name in sorted((names & algorithm_names) | modules)]
    assert not named, named
