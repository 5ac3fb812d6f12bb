"""The plug-in boundary in code: which package may import which.

Every module under ``src/motionbase`` is parsed with :mod:`ast` (nothing is imported) and
its imports are collected at any depth: at module level, inside functions and classes, and
inside ``if TYPE_CHECKING:`` blocks (a type-only import is still a dependency a reader must
know). The rules (issue 14, "Layering"):

* the maths (``motionbase.platform``, ``motionbase.washout``) never imports the edges
  (``motionbase.io``) nor anything that runs the loop or does I/O around it
  (:data:`LOOP_AND_IO`), neither directly nor through the modules it loads;
* the edges (``motionbase.io``) never import the pipeline nor the programs that run it
  (:data:`RUNNERS`), neither directly nor through the modules they load when imported;
* no module imports another package's private names (``from motionbase.x import _y``, or a
  module ``motionbase.x._mod``); the packages are ``motionbase`` (its top-level modules),
  ``motionbase.platform``, ``motionbase.washout`` and ``motionbase.io``.

The checker itself is tested on crafted sources first, so a green run means the rules were
really applied.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

import pytest

import motionbase

ROOT = Path(motionbase.__file__).parent

#: The pipeline and the programs that run it: what the edges may not import.
RUNNERS = (
    "motionbase.pipeline",
    "motionbase.app",
    "motionbase.cli",
    "motionbase.teleop",
)

#: What the maths may not import: the edges, the pipeline and its stages, everything that
#: runs them (the programs, the tuner, the objective test, the report), and the modules that
#: keep time or catch signals.
LOOP_AND_IO = (
    "motionbase.io",
    *RUNNERS,
    "motionbase.stages",
    "motionbase.tuning",
    "motionbase.omct",
    "motionbase.report",
    "motionbase.pacing",
    "motionbase.stopping",
)

MATH_PACKAGES = ("motionbase.platform", "motionbase.washout")
SUBPACKAGES = ("motionbase.platform", "motionbase.washout", "motionbase.io")


@dataclass(frozen=True)
class Import:
    """One imported name: ``module`` (absolute), ``name`` (None for ``import module``)."""

    module: str
    name: str | None
    line: int
    top_level: bool  # executed when the importing module is imported

    @property
    def target(self) -> str:
        return self.module if self.name is None else f"{self.module}.{self.name}"


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def imports_of(source: str, module: str, is_package: bool = False) -> list[Import]:
    """Every import in ``source`` (the text of ``module``), relative ones made absolute."""
    tree = ast.parse(source)
    package = module if is_package else module.rpartition(".")[0]
    found: list[Import] = []

    def visit(node: ast.AST, top_level: bool) -> None:
        if isinstance(node, ast.Import):
            for alias in node.names:
                found.append(Import(alias.name, None, node.lineno, top_level))
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            for alias in node.names:
                found.append(Import(mod, alias.name, node.lineno, top_level))
        # the body of a function runs later; a TYPE_CHECKING block never runs
        for child in ast.iter_child_nodes(node):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda):
                visit(child, False)
            elif isinstance(node, ast.If) and _is_type_checking(node.test) and child in node.body:
                visit(child, False)
            else:
                visit(child, top_level)

    visit(tree, True)
    return found


def _within(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


def package_of(module: str) -> str:
    """The layering package a module belongs to (``motionbase`` for the top-level ones)."""
    for pkg in SUBPACKAGES:
        if _within(module, pkg):
            return pkg
    return "motionbase"


def private_imports(module: str, imports: list[Import]) -> list[str]:
    """The imports of another package's private (underscore) names or modules."""
    bad = []
    for imp in imports:
        if not _within(imp.module, "motionbase"):
            continue
        parts = imp.target.split(".")
        for k, part in enumerate(parts):
            if part.startswith("_") and not part.startswith("__"):
                owner = ".".join(parts[:k])  # the module or package the private name lives in
                if package_of(owner) != package_of(module):
                    bad.append(f"{module}:{imp.line} imports {imp.target}")
                break
    return bad


def forbidden_imports(module: str, imports: list[Import], forbidden: tuple[str, ...]) -> list[str]:
    """The imports (at any depth) of a module within one of ``forbidden``."""
    return [
        f"{module}:{imp.line} imports {imp.target}"
        for imp in imports
        if any(_within(imp.module, f) or _within(imp.target, f) for f in forbidden)
    ]


def load_graph(files: dict[str, str]) -> dict[str, list[Import]]:
    """Module -> its imports, for sources ``{module: text}`` (a package as ``pkg.__init__``)."""
    graph = {}
    for name, text in files.items():
        is_package = name.endswith(".__init__")
        mod = name.removesuffix(".__init__")
        graph[mod] = imports_of(text, mod, is_package)
    return graph


def loaded_by(module: str, graph: dict[str, list[Import]]) -> dict[str, str]:
    """The motionbase modules importing ``module`` loads (each with the chain that loads it).

    Follows the imports run at import time (module level, not in functions nor in
    ``TYPE_CHECKING`` blocks), and the packages above every module loaded.
    """
    chains: dict[str, str] = {}
    todo = [(module, module)]
    while todo:
        mod, chain = todo.pop()
        for imp in graph.get(mod, []):
            if not imp.top_level or not _within(imp.module, "motionbase"):
                continue
            names = [imp.module] + ([imp.target] if imp.target in graph else [])
            for name in names:
                parts = name.split(".")
                for k in range(1, len(parts) + 1):
                    dep = ".".join(parts[:k])
                    if dep in graph and dep not in chains and dep != module:
                        chains[dep] = f"{chain} -> {dep}"
                        todo.append((dep, chains[dep]))
    return chains


def layering_problems(graph: dict[str, list[Import]]) -> list[str]:
    """Every breach of the rules in an import graph (empty when the layering holds)."""
    problems = []
    for mod, imports in sorted(graph.items()):
        problems += private_imports(mod, imports)
        if any(_within(mod, p) for p in MATH_PACKAGES):
            problems += forbidden_imports(mod, imports, LOOP_AND_IO)
            problems += [
                f"{mod} loads {dep} ({chain})"
                for dep, chain in loaded_by(mod, graph).items()
                if any(_within(dep, f) for f in LOOP_AND_IO)
            ]
        if _within(mod, "motionbase.io"):
            problems += forbidden_imports(mod, imports, RUNNERS)
            problems += [
                f"{mod} loads {dep} ({chain})"
                for dep, chain in loaded_by(mod, graph).items()
                if any(_within(dep, f) for f in RUNNERS)
            ]
    return problems


def project_graph() -> dict[str, list[Import]]:
    files = {}
    for path in sorted(ROOT.rglob("*.py")):
        name = module_name(path)
        files[name + ".__init__" if path.name == "__init__.py" else name] = path.read_text()
    return load_graph(files)


# --------------------------------------------------------------------------- the checker


def test_imports_are_found_at_every_depth_and_made_absolute() -> None:
    src = (
        "from typing import TYPE_CHECKING\n"
        "import motionbase.io.mcap_log\n"
        "from . import filters\n"
        "from ..safety import limit_command\n"
        "if TYPE_CHECKING:\n"
        "    from motionbase.tuning import Score\n"
        "def f():\n"
        "    from motionbase.pipeline import run\n"
        "class C:\n"
        "    def g(self):\n"
        "        import motionbase.app\n"
    )
    imports = imports_of(src, "motionbase.washout.classical")
    got = {(i.target, i.top_level) for i in imports}
    assert ("motionbase.io.mcap_log", True) in got
    assert ("motionbase.washout.filters", True) in got
    assert ("motionbase.safety.limit_command", True) in got
    assert ("motionbase.tuning.Score", False) in got  # type-only: found, not run
    assert ("motionbase.pipeline.run", False) in got
    assert ("motionbase.app", False) in got


@pytest.mark.parametrize(
    ("module", "line"),
    [
        ("motionbase.platform.rus6", "from motionbase.io.mcap_log import McapLogger"),
        ("motionbase.washout.classical", "from motionbase.pipeline import PipelineOutput"),
        ("motionbase.washout.cueing", "import motionbase.stages"),
        ("motionbase.platform.robot", "from motionbase import teleop"),
        ("motionbase.io.motor_output", "from motionbase.pipeline import StopRequest"),
        ("motionbase.io.scene", "from motionbase import app"),
        ("motionbase.io.mcap_source", "from motionbase.safety import _brake_speed"),
        ("motionbase.washout.classical", "from motionbase.safety import _brake_speed"),
        ("motionbase.washout.filters", "from motionbase.platform._rus6_kernels import x"),
        ("motionbase.stages", "from motionbase.platform import _rus6_kernels"),
    ],
)
def test_the_checker_catches_a_breach(module: str, line: str) -> None:
    """Each crafted line breaks one rule, also inside a function."""
    graph = load_graph({module: line + "\n"})
    assert layering_problems(graph), line
    inside = load_graph({module: "def f():\n    " + line + "\n"})
    assert layering_problems(inside), f"in a function: {line}"


def test_the_checker_follows_what_a_module_loads() -> None:
    """platform -> a top-level helper -> io is a breach; the same in a function is deferred."""
    graph = load_graph(
        {
            "motionbase.platform.robot": "from motionbase import helper\n",
            "motionbase.helper": "from motionbase.io import mcap_log\n",
            "motionbase.io.__init__": "",
            "motionbase.io.mcap_log": "",
        }
    )
    problems = layering_problems(graph)
    assert problems and "motionbase.platform.robot -> motionbase.helper -> motionbase.io" in (
        "\n".join(problems)
    )
    deferred = load_graph(
        {
            "motionbase.io.report_plots": "from motionbase import report\n",
            "motionbase.report": "def f():\n    from motionbase.pipeline import PipelineConfig\n",
            "motionbase.pipeline": "",
        }
    )
    assert layering_problems(deferred) == []


@pytest.mark.parametrize(
    ("module", "line"),
    [
        ("motionbase.platform.rrr3", "from motionbase.platform import _rrr3_kernels as _k"),
        ("motionbase.platform.stewart6", "from motionbase.platform._rus6_kernels import _wrap"),
        ("motionbase.stages", "from motionbase.safety import limit_kernel"),
        ("motionbase.io.mcap_source", "from motionbase.io.mcap_log import MCAP_MAGIC"),
        ("motionbase.io.manoeuvres", "from motionbase.washout.params import WashoutParams"),
        ("motionbase.platform.robot", "from motionbase.safety import ActuatorLimits"),
        ("motionbase.pipeline", "from motionbase import __version__"),
        ("motionbase.app", "from motionbase.io.pipeline_log import PipelineLog"),
    ],
)
def test_the_checker_allows_what_the_rules_allow(module: str, line: str) -> None:
    """Private names within their own package, io using the maths, runners using io."""
    assert layering_problems(load_graph({module: line + "\n"})) == []


# --------------------------------------------------------------------------- the project


def test_every_module_is_seen() -> None:
    graph = project_graph()
    for name in ("motionbase.platform.rus6", "motionbase.washout.classical", "motionbase.io.base"):
        assert name in graph
    assert len(graph) == len(list(ROOT.rglob("*.py")))


def test_the_project_keeps_its_layers() -> None:
    problems = layering_problems(project_graph())
    assert problems == [], "\n".join(problems)
