"""The package's layers point one way, down the data flow (docs/ARCHITECTURE.md).

Every ``import`` of an img2dmp module, at module level or inside a function, is read from
the source and checked against the layer order; a cycle between modules is refused too.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "img2dmp"

#: Lower layers first; a module may import its own layer and those below it.
LAYERS = [
    {"__init__", "_files", "_lazy", "_processes", "_progress", "config", "errors", "models"},
    {"dmp", "metrics"},
    {"data", "interop"},
    {"nn", "checkpoint", "familiar"},
    {"training", "train"},
    {"predict", "page"},
    {"evaluate", "export"},
    {"robot"},
    {"pipeline"},
    {"web"},
    {"commands", "cli", "__main__"},
]


def _top(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def _layer(module: str) -> int:
    top = _top(module)
    for i, names in enumerate(LAYERS):
        if top in names:
            return i
    raise AssertionError(f"module {module} is in no layer of tests/test_architecture.py")


def _module_name(path: Path) -> str:
    rel = path.relative_to(SRC.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _imports(path: Path) -> set[str]:
    """img2dmp modules imported anywhere in a file (relative imports resolved)."""
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.split(".")[0] == "img2dmp"}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            if mod.split(".")[0] != "img2dmp":
                continue
            for a in node.names:  # "from . import x" may name a module
                sub = f"{mod}.{a.name}"
                out.add(sub if (SRC.parent / Path(*sub.split("."))).exists() else mod)
    return out


def _graph() -> dict[str, set[str]]:
    return {_module_name(p): _imports(p) - {_module_name(p)} for p in SRC.rglob("*.py")}


def test_every_import_points_down_the_layers():
    wrong = []
    for module, imported in sorted(_graph().items()):
        for other in sorted(imported):
            if _layer(other) > _layer(module):
                wrong.append(f"{module} imports {other}")
    assert not wrong, "imports against the data flow:\n" + "\n".join(wrong)


def test_no_import_cycle():
    graph = {m: {i for i in deps if i in _graph_keys()} for m, deps in _graph().items()}
    state: dict[str, int] = {}

    def visit(m, stack):
        state[m] = 1
        for n in graph.get(m, ()):
            if state.get(n) == 1:
                # a package importing its own submodules is not a cycle of the layers
                cycle = stack[stack.index(n) :] + [n] if n in stack else [m, n]
                if not all(c.startswith(cycle[0].rsplit(".", 1)[0]) for c in cycle):
                    pytest.fail("import cycle: " + " -> ".join(cycle))
            elif n not in state:
                visit(n, stack + [n])
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [m])


def _graph_keys() -> set[str]:
    return {_module_name(p) for p in SRC.rglob("*.py")}


def test_the_checker_sees_a_wrong_import(tmp_path):
    # The test can fail: an upward import written into a lower layer is found.
    f = SRC / "dmp" / "config.py"
    assert "img2dmp.training" not in _imports(f)
    fake = tmp_path / "x.py"
    fake.write_text("from img2dmp.training import train\n")
    assert {"img2dmp.training"} <= {m for m in _imports_of_text(fake)}
    assert _layer("img2dmp.training") > _layer("img2dmp.dmp.config")


def _imports_of_text(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    return {
        n.module
        for n in ast.walk(tree)
        if isinstance(n, ast.ImportFrom) and n.module and n.module.startswith("img2dmp")
    }


#: Functions allowed past the limit: the numba kernel builder (its kernels are one unit).
LONG_ALLOWED = {("dmp/_kernels.py", "_build")}
MAX_FUNCTION_LINES = 80


def test_no_function_is_longer_than_a_screen():
    long = []
    for path in sorted(SRC.rglob("*.py")):
        rel = path.relative_to(SRC).as_posix()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1  # def line to last line, docstring too
                if n > MAX_FUNCTION_LINES and (rel, node.name) not in LONG_ALLOWED:
                    long.append(f"{rel}:{node.lineno} {node.name} ({n} lines)")
    assert not long, "functions longer than 80 lines:\n" + "\n".join(long)
