"""The code's layers: each module imports only from its floor and below, every import is one the graph sees (no
project module imported by a string), no import cycle between modules, and reporting without the training stack."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ("sb3_sgfd", "sgfd_envs", "sgfd_zoo", "sgfd_analysis", "sgfd_cli")
#: The floors, lowest first: a module imports from its own floor and those below. The figures (sgfd_analysis) are
#: drawn from the zoo's runs; the ``sgfd-zoo`` command (sgfd_cli) dispatches to every command, the figures' included,
#: so it stands above both packages: no module of a package imports from a floor above its package's.
FLOORS = (("sgfd_envs",), ("sb3_sgfd",), ("sgfd_zoo",), ("sgfd_analysis",), ("sgfd_cli",))
#: Modules that import project modules by a name they compute, and the table (a literal dict, its values the
#: modules) those names come from: the graph takes them from the table. None today: every import is one the graph
#: sees (the old paths of saved files are plain modules that re-export, e.g. sb3_sgfd.policies).
COMPUTED_IMPORTS: dict[str, str] = {}
#: Functions that import by a string the modules a user names (``--gym-packages``: their own env packages, as
#: rl-zoo3's scripts import them), by module: nothing of the project's is imported there.
USER_NAMED_IMPORTS = {"sgfd_zoo.arguments": "import_gym_packages"}


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


def string_imports(node: ast.AST) -> list[ast.expr]:
    """The module argument of every ``import_module(...)`` and ``__import__(...)`` call in ``node``."""
    calls = [child for child in ast.walk(node) if isinstance(child, ast.Call) and child.args]
    names = {"import_module", "__import__"}
    return [
        call.args[0]
        for call in calls
        if (isinstance(call.func, ast.Name) and call.func.id in names)
        or (isinstance(call.func, ast.Attribute) and call.func.attr in names)
    ]


def names_a_project_module(argument: ast.expr) -> bool:
    """Whether a string import's argument may name a project module: one that reads as a project module's name, or
    one whose package cannot be read from the source (a variable, an f-string starting with a placeholder)."""
    if isinstance(argument, ast.Constant) and isinstance(argument.value, str):
        return argument.value.split(".")[0] in PACKAGES
    if isinstance(argument, ast.JoinedStr) and argument.values and isinstance(argument.values[0], ast.Constant):
        prefix = str(argument.values[0].value)
        return "." not in prefix or prefix.split(".")[0] in PACKAGES
    return True


def computed_imports(name: str, tree: ast.Module) -> set[str]:
    """The modules in the values of module ``name``'s table :data:`COMPUTED_IMPORTS` names (a literal dict)."""
    for statement in tree.body:
        if isinstance(statement, ast.Assign | ast.AnnAssign) and statement.value is not None:
            targets = statement.targets if isinstance(statement, ast.Assign) else [statement.target]
            if COMPUTED_IMPORTS[name] in [ast.unparse(target) for target in targets]:
                return {module for modules in ast.literal_eval(statement.value).values() for module in modules}
    raise AssertionError(f"{name}: no table {COMPUTED_IMPORTS[name]} at its top level")


def parsed_modules() -> dict[str, ast.Module]:
    """Every module of :data:`PACKAGES` by name, parsed."""
    modules = {}
    for package in PACKAGES:
        for path in (REPO / package).rglob("*.py"):
            name = ".".join(path.relative_to(REPO).with_suffix("").parts).removesuffix(".__init__")
            modules[name] = ast.parse(path.read_text())
    return modules


def module_imports() -> dict[str, set[str]]:
    """Module -> the project modules it imports, wherever in it (see ``all_imports``), and those it imports by a
    computed name (:data:`COMPUTED_IMPORTS`)."""
    graph = {}
    for name, tree in parsed_modules().items():
        graph[name] = all_imports(tree) | (computed_imports(name, tree) if name in COMPUTED_IMPORTS else set())
    return {name: {dep for dep in deps if dep in graph and dep != name} for name, deps in graph.items()}


def floor(module: str) -> int:
    """The floor of ``module``: that of the longest name in :data:`FLOORS` that is it or a package holding it."""
    holders = [name for names in FLOORS for name in names if module == name or module.startswith(f"{name}.")]
    longest = max(holders, key=len)
    return next(index for index, names in enumerate(FLOORS) if longest in names)


def test_the_import_graph_counts_lazy_and_type_only_imports():
    code = "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import a.b\ndef f():\n    from c import d\n"
    assert {"a.b", "c", "c.d"} <= all_imports(ast.parse(code))
    # the objectives see the algorithm through a Protocol: no edge back to the training loop
    graph = module_imports()
    assert "sb3_sgfd.common.representation" in graph["sb3_sgfd.common.encoder_sac"]
    assert "sb3_sgfd.common.encoder_sac" not in graph["sb3_sgfd.common.representation"]


def test_a_project_module_imported_by_a_string_is_refused():
    def flagged(code: str) -> list[bool]:
        return [names_a_project_module(argument) for argument in string_imports(ast.parse(code))]

    assert flagged("import importlib\nimportlib.import_module('sgfd_analysis.figures')") == [True]
    assert flagged("from importlib import import_module\ndef f(module):\n    return import_module(module)") == [True]
    assert flagged("__import__(f'sgfd_zoo.{name}')\nimportlib.import_module(f'{package}.x')") == [True, True]
    assert flagged("importlib.import_module(f'dm_control.suite.{domain}')\n__import__('yaml')") == [False, False]
    found = {
        name: [ast.unparse(argument) for argument in string_imports(tree) if names_a_project_module(argument)]
        for name, tree in parsed_modules().items()
        if name not in COMPUTED_IMPORTS
    }
    for name, function in USER_NAMED_IMPORTS.items():
        (user_named,) = [node for node in ast.walk(parsed_modules()[name]) if getattr(node, "name", "") == function]
        assert len(string_imports(user_named)) == len(found[name]) == 1  # that function's, and nothing else
        del found[name]
    assert not {name: arguments for name, arguments in found.items() if arguments}


def test_importing_the_packages_installs_no_import_hook():
    # No sys.meta_path finder and no path hook of the project's: old module paths are plain modules
    # (sb3_sgfd.policies, ...). (absl, which tensorboard brings, installs a finder of its own: not ours.)
    code = "import sys; before = (list(sys.meta_path), list(sys.path_hooks)); "
    code += "import sb3_sgfd, sgfd_envs, sgfd_zoo, sgfd_analysis, sgfd_cli; "
    code += "added = [f for f in sys.meta_path if f not in before[0]]; "
    code += "added += [h for h in sys.path_hooks if h not in before[1]]; "
    code += "print(sorted({getattr(f, '__module__', None) or type(f).__module__ for f in added}))"
    added = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO)
    modules = ast.literal_eval(added.stdout.strip().splitlines()[-1])
    assert not [module for module in modules if module.split(".")[0] in PACKAGES], modules


def test_each_module_imports_from_its_floor_and_below():
    graph = module_imports()
    upward = sorted(f"{name} -> {dep}" for name, deps in graph.items() for dep in deps if floor(dep) > floor(name))
    assert not upward, upward
    assert floor("sgfd_cli.commands") > floor("sgfd_analysis.figures") > floor("sgfd_zoo.runs.folders")
    # the command's reach into the figures and the zoo is an import the graph sees
    assert {"sgfd_analysis.figures", "sgfd_analysis.correlation", "sgfd_zoo.training"} <= graph["sgfd_cli.commands"]


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


#: what ``sgfd-zoo plot``, ``evaluate``'s tables, ``-h`` and the sweep's planning load: the command, the argument
#: checks and the keys, the report wing, the run folders, records, files, checkpoints, locks and provenance, the
#: sweep's plan and progress board
REPORTING = [
    "sgfd_cli.commands",
    "sgfd_zoo.arguments",
    "sgfd_zoo.algos",
    "sgfd_zoo.report.evaluate",
    "sgfd_zoo.report.plot",
    "sgfd_zoo.report.statistics",
    "sgfd_zoo.runs.folders",
    "sgfd_zoo.runs.records",
    "sgfd_zoo.runs.files",
    "sgfd_zoo.runs.checkpoints",
    "sgfd_zoo.runs.locks",
    "sgfd_zoo.runs.provenance",
    "sgfd_zoo.sweep.plan",
    "sgfd_zoo.sweep.progress",
]


def test_reporting_imports_neither_torch_nor_rl_zoo3():
    code = f"import sys, {', '.join(REPORTING)}; "
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


def _private_module(module: str) -> bool:
    """Whether ``module`` is a private module of another package (a part of its path begins with ``_``)."""
    return module.split(".")[0] not in PACKAGES and any(part.startswith("_") for part in module.split(".")[1:])


def test_no_module_reaches_into_another_packages_internals() -> None:
    """Other packages through their public names only: no private module (``ray._private``, ``ray._raylet``), no
    ``sys.argv`` rewritten for another package's parser, no attribute of another package's module replaced."""
    others = {"rl_zoo3", "ray", "stable_baselines3", "sb3_contrib", "gymnasium"}
    reached = []
    for name, tree in parsed_modules().items():
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                modules = [node.module, *(f"{node.module}.{alias.name}" for alias in node.names)]
                reached += [f"{name} imports {module}" for module in modules if _private_module(module)]
            elif isinstance(node, ast.Import):
                reached += [f"{name} imports {a.name}" for a in node.names if _private_module(a.name)]
            elif isinstance(node, ast.Assign) and "sys.argv" in map(ast.unparse, node.targets):
                reached.append(f"{name} sets sys.argv")
            elif isinstance(node, ast.Call) and ast.unparse(node.func) == "setattr" and node.args:
                owner = ast.unparse(node.args[0])
                reached += [f"{name} replaces an attribute of {owner}"] if owner.split(".")[0] in others else []
    assert not reached, reached


def project_classes() -> dict[str, list[str]]:
    """Every class the packages define, by name, with the names of its bases as written."""
    classes: dict[str, list[str]] = {}
    for name, tree in parsed_modules().items():
        for node in ast.walk(tree):
            if isinstance(node, ast.ClassDef):
                classes[f"{name}.{node.name}"] = [ast.unparse(base).split(".")[-1] for base in node.bases]
    return classes


def test_no_class_has_more_than_one_base_of_the_project():
    # Held, not inherited: the training loop holds its update runner, the buffer its frame store and episode index;
    # a class extends at most one of the project's (SB3's, torch's and typing's bases aside)
    classes = project_classes()
    ours = {qualified.rsplit(".", 1)[1] for qualified in classes}
    assert {"EncoderSAC", "DomainReplayBuffer", "SGFDWeighting"} <= ours
    stacked = {name: bases for name, bases in classes.items() if len([base for base in bases if base in ours]) > 1}
    assert not stacked, stacked
