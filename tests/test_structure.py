"""The package's shape (docs/architecture.md): no import circle, a small top
level, no oversized module or function, and tests that mirror the package."""

from __future__ import annotations

import ast
from pathlib import Path

import drqn_jax

PACKAGE = Path(drqn_jax.__file__).resolve().parent
TESTS = Path(__file__).resolve().parent

#: At most this many modules directly in drqn_jax/ (``__init__.py`` included).
MAX_TOP_LEVEL_MODULES = 12
#: No module longer than this many lines.
MAX_MODULE_LINES = 500
#: No function longer than this many lines, its docstring left out ("no function much
#: over 60 lines": a builder that returns closures, as make_network, may reach it); a
#: nested function counts in its parent too.
MAX_FUNCTION_LINES = 90


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def modules() -> dict[str, Path]:
    return {module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def imports(path: Path, known: set[str]) -> set[str]:
    """The package's modules that ``path`` imports anywhere (top level, functions,
    ``TYPE_CHECKING`` blocks): ``from a.b import c`` counts as ``a.b.c`` when that is a
    module, else ``a.b``."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("drqn_jax"):
            for alias in node.names:
                child = f"{node.module}.{alias.name}"
                found.add(child if child in known else node.module)
        elif isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.startswith("drqn_jax")}
    return found & known


def import_graph() -> dict[str, set[str]]:
    """Module → the package modules it imports, the package's own ``__init__`` left out
    (it imports the public names from everywhere, and ``__version__`` is read from it)."""
    mods = modules()
    known = set(mods) - {"drqn_jax"}
    return {name: imports(path, known) - {name} for name, path in mods.items() if name in known}


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_circle_finder_finds_a_circle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert circles(graph) == [["a", "b", "c"]]
    assert circles({"a": {"b"}, "b": set()}) == []


def test_no_module_imports_itself_back():
    assert circles(import_graph()) == []


def test_the_top_level_is_small():
    top = sorted(p.name for p in PACKAGE.glob("*.py"))
    assert len(top) <= MAX_TOP_LEVEL_MODULES, top


def test_no_module_is_oversized():
    long = {
        name: n
        for name, path in modules().items()
        if (n := len(path.read_text().splitlines())) > MAX_MODULE_LINES
    }
    assert long == {}


def function_lines(node: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    """``node``'s lines, decorators and docstring left out."""
    lines = node.end_lineno - node.lineno + 1
    first = node.body[0]
    if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
        lines -= first.end_lineno - first.lineno + 1
    return lines


def long_functions(path: Path, limit: int) -> dict[str, int]:
    functions = (
        n
        for n in ast.walk(ast.parse(path.read_text()))
        if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef)
    )
    return {f"{path.name}:{f.name}": n for f in functions if (n := function_lines(f)) > limit}


def test_the_function_counter_counts_code_not_docstrings(tmp_path):
    body = "\n".join(f"    x{i} = {i}" for i in range(5))
    source = tmp_path / "m.py"
    source.write_text(f'def f():\n    """Doc\n\n    more."""\n{body}\n')
    assert long_functions(source, 6) == {}  # the def line and five, not the docstring's three
    assert long_functions(source, 5) == {"m.py:f": 6}


def test_no_function_is_oversized():
    long = {}
    for path in modules().values():
        long |= long_functions(path, MAX_FUNCTION_LINES)
    assert long == {}


def test_the_tests_mirror_the_package():
    """Every test file of a package's module sits in that package's folder of tests/
    (``tests/learners/dqn/test_train.py`` tests ``drqn_jax/learners/dqn/train.py``)."""
    misplaced = []
    for path in TESTS.rglob("test_*.py"):
        folder = path.parent.relative_to(TESTS)
        if folder.parts and folder.parts[0] == "benchmarks":
            continue
        module = path.stem.removeprefix("test_")
        here = PACKAGE.joinpath(*folder.parts)
        elsewhere = [p for p in PACKAGE.rglob(f"{module}.py") if p.parent != here]
        if not (here / f"{module}.py").is_file() and elsewhere:
            misplaced.append(f"{path.relative_to(TESTS)} (module in {elsewhere[0].parent})")
    assert misplaced == []
