"""No module imports another that imports it back (directly or round a longer circle), counting imports
inside functions too; the plugin registry's lazy load (`pipeline._load_plugins`) is the one accepted
back-reference."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TREES = {"evstream": ROOT / "evstream", "evstream.sources": ROOT / "sources", "evstream.sinks": ROOT / "sinks"}
ACCEPTED = {("evstream.pipeline", "_load_plugins")}  # (module, function) whose imports are not counted


def _modules() -> dict[str, Path]:
    found = {}
    for prefix, folder in TREES.items():
        for path in folder.rglob("*.py"):
            rel = path.relative_to(folder).with_suffix("").parts
            if prefix == "evstream" and rel[0] in ("sources", "sinks"):
                continue
            parts = rel[:-1] if rel[-1] == "__init__" else rel
            found[".".join((prefix, *parts))] = path
    return found


def _imports(name: str, path: Path, modules: dict) -> set[str]:
    """The project modules `name` imports (a `from package import sub` counts as importing sub)."""
    tree = ast.parse(path.read_text())
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    skip = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef) and (name, node.name) in ACCEPTED:
            skip.update(id(n) for n in ast.walk(node))
    out = set()
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join([*up, *([base] if base else [])])
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
        else:
            continue
        for target in targets:
            while target and target not in modules:  # `import evstream.sinks.x.y` -> the module that exists
                target = target.rpartition(".")[0]
            if target and target != name:
                out.add(target)
    return out


def test_no_import_cycles():
    modules = _modules()
    graph = {name: _imports(name, path, modules) for name, path in modules.items()}
    cycles = []
    state: dict[str, int] = {}  # 1 on the stack, 2 done

    def visit(node, stack):
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                cycles.append(" -> ".join([*stack[stack.index(nxt):], nxt]))
            elif nxt not in state:
                visit(nxt, stack)
        stack.pop()
        state[node] = 2

    for name in sorted(graph):
        if name not in state:
            visit(name, [])
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


def test_the_graph_sees_imports():
    """The check above is only worth something if it finds the edges: a few that must be there."""
    modules = _modules()
    assert "evstream.cli.common" in _imports("evstream.cli.replay", modules["evstream.cli.replay"], modules)
    assert "evstream.sources" in _imports("evstream.api", modules["evstream.api"], modules)
    assert "evstream.cli.subscriber" in _imports("evstream.cli.subscribe", modules["evstream.cli.subscribe"], modules)


def test_cli_modules_are_small():
    big = {p.name: n for p in (ROOT / "evstream" / "cli").glob("*.py") if (n := len(p.read_text().splitlines())) > 300}
    assert not big, f"CLI modules over 300 lines: {big}"
