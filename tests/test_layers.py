"""The house's stack: data flows one way, robots/ -> lab/ -> app/, and no two modules import each
other, directly or round a loop (a function-level import counts as much as one at the top)."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("robots", "lab", "app")
LAYER = {name: i for i, name in enumerate(PACKAGES)}


def _modules() -> dict[str, Path]:
    return {".".join(p.relative_to(ROOT).with_suffix("").parts): p
            for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")}


def _imports(path: Path, modules: dict[str, Path]) -> set[str]:
    """The modules of the house that path imports: `from pkg import sub` names the submodule; an import
    of a package's face (its __init__) is left out, as the face only hands names on."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [f"{node.module}.{a.name}" for a in node.names] + [node.module]
        else:
            continue
        out |= {n for n in names if n in modules and modules[n].name != "__init__.py"}
    return out


GRAPH = {name: _imports(path, _modules()) for name, path in _modules().items() if path.name != "__init__.py"}


@pytest.mark.parametrize("module", sorted(GRAPH))
def test_no_module_imports_a_layer_above_its_own(module):
    above = {m for m in GRAPH[module] if LAYER[m.split(".")[0]] > LAYER[module.split(".")[0]]}
    assert not above, f"{module} imports {sorted(above)}: data flows robots -> lab -> app only"


def test_no_import_circle():  # (lab.problem.encoding <-> tree_encoding was one until 2026-12-05)
    """Depth-first search for a back edge; the loop found is named in full."""
    state, stack = {}, []

    def visit(m):
        state[m] = "open"
        stack.append(m)
        for n in sorted(GRAPH.get(m, ())):
            if state.get(n) == "open":
                loop = stack[stack.index(n):] + [n]
                pytest.fail("import circle: " + " -> ".join(loop))
            if n not in state:
                visit(n)
        stack.pop()
        state[m] = "done"

    for m in sorted(GRAPH):
        if m not in state:
            visit(m)
