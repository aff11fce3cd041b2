"""The workbench's module structure, read from the source with ``ast`` (nothing imported).

The panes talk to the app by messages only (``workbench.tui.messages``) and are handed
plain data back: no pane imports the app or another pane, none reads the app's attributes,
and no module of ``workbench/tui`` takes part in an import circle.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

TUI = Path(__file__).resolve().parents[2] / "workbench" / "tui"
PANES = sorted((TUI / "panes").glob("*.py"))
# what a widget may use of ``self.app``: Textual's own services, not the workbench's state
APP_SERVICES = {"call_from_thread", "notify"}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(TUI.parents[1]).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imported_modules(path: Path, known: set[str]) -> set[str]:
    """The modules of ``known`` that ``path`` imports (``TYPE_CHECKING`` blocks included)."""
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                source = f"{base}.{node.module}" if node.module else base
            else:
                source = node.module or ""
            # ``from pkg import mod`` imports the module pkg.mod
            targets = [source, *(f"{source}.{a.name}" for a in node.names)]
        else:
            continue
        for target in targets:
            # ``import a.b.c`` imports a.b and a too
            parts = target.split(".")
            out.update(m for k in range(1, len(parts) + 1) if (m := ".".join(parts[:k])) in known)
    out.discard(name)
    return out


def import_graph() -> dict[str, set[str]]:
    """Module → the ``workbench.tui`` modules it imports."""
    paths = sorted(TUI.rglob("*.py"))
    known = {module_name(p) for p in paths}
    return {module_name(p): imported_modules(p, known) for p in paths}


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_graph_sees_relative_and_absolute_imports():
    """The parser itself: the app imports every pane, and the panes their shared modules."""
    graph = import_graph()
    assert {f"workbench.tui.panes.{p.stem}" for p in PANES if p.stem != "__init__"} <= graph[
        "workbench.tui.app"
    ]
    assert {"workbench.tui.messages", "workbench.tui.parsers"} <= graph[
        "workbench.tui.panes.synthesis"
    ]
    # a circle is found when there is one
    assert import_cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_no_import_circle_in_the_workbench():
    assert import_cycles(import_graph()) == []


@pytest.mark.parametrize("path", PANES, ids=lambda p: p.stem)
def test_a_pane_does_not_import_the_app_or_another_pane(path):
    imported = import_graph()[module_name(path)]
    assert module_name(TUI / "app.py") not in imported
    panes = module_name(TUI / "panes" / "__init__.py") + "."
    assert not {m for m in imported if m.startswith(panes)}, imported


@pytest.mark.parametrize("path", PANES, ids=lambda p: p.stem)
def test_a_pane_does_not_reach_into_the_app(path):
    """No ``self.app.run_stage(...)``, ``app = self.app; app.law``: only Textual's services."""
    tree = ast.parse(path.read_text(), str(path))
    parent = {child: node for node in ast.walk(tree) for child in ast.iter_child_nodes(node)}
    bad = [
        f"line {node.lineno}: {ast.unparse(parent.get(node, node))}"
        for node in ast.walk(tree)
        if isinstance(node, ast.Attribute)
        and node.attr == "app"
        and not (
            isinstance(up := parent.get(node), ast.Attribute)
            and up.value is node
            and up.attr in APP_SERVICES
        )
    ]
    assert not bad, bad


def main() -> None:
    """Print the import graph of ``workbench/tui`` and its circles (none, we hope)."""
    graph = import_graph()
    for module, imports in sorted(graph.items()):
        short = sorted(m.removeprefix("workbench.tui.") for m in imports)
        print(f"{module} -> {', '.join(short) or '-'}")
    cycles = import_cycles(graph)
    edges = sum(map(len, graph.values()))
    print(f"{len(graph)} modules, {edges} imports, circles: {cycles or 'none'}")


if __name__ == "__main__":
    main()
