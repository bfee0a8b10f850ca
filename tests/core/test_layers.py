"""Arrows point one way: every import (also those inside functions) of every module, checked against
the layers of the README's layout, and no import circle among the modules of prc_slam and data_tools."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

#: application modules of prc_slam (commands, their jobs, the live receiver that opens sockets and
#: readers): they may import everything below them
APPLICATION = ("prc_slam.jobs", "prc_slam.live", "prc_slam.cli", "prc_slam.preprocess", "prc_slam.jobs.bench")
#: the console entry point, above everything
ENTRY = ("prc_slam.__main__",)
VIEWER = ("prc_slam.viz",)


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports(path: Path) -> set[str]:
    """Every module ``path`` imports, resolved to absolute names."""
    tree = ast.parse(path.read_text())
    here = module_name(path).split(".")
    package = here if path.name == "__init__.py" else here[:-1]
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package[: len(package) - node.level + 1] + ([base] if base else []))
            out.add(base)
            out.update(f"{base}.{a.name}" for a in node.names)
    return out


def modules(package: str) -> dict[str, Path]:
    return {module_name(p): p for p in (ROOT / package).rglob("*.py")}


def layer(name: str) -> str:
    if name.startswith(ENTRY):
        return "entry"
    if name.startswith("data_tools"):
        return "data"
    if name.startswith(APPLICATION):
        return "application"
    if name.startswith(VIEWER):
        return "viewer"
    return "core"


FORBIDDEN = {
    "core": ("data_tools", *VIEWER, *APPLICATION, *ENTRY),
    "data": (*VIEWER, *APPLICATION, *ENTRY),
    "viewer": (*APPLICATION, *ENTRY),
    "application": ("prc_slam.cli", *ENTRY),
    "entry": (),
}


def test_no_module_imports_from_a_layer_above_it():
    problems = []
    for name, path in {**modules("prc_slam"), **modules("data_tools")}.items():
        own = layer(name)
        forbidden = tuple(f for f in FORBIDDEN[own] if not name.startswith(f))
        for imported in imports(path):
            if imported.startswith(forbidden):
                problems.append(f"{name} ({own}) imports {imported}")
    assert not problems, "\n".join(sorted(problems))


def under_type_checking(tree: ast.Module) -> set[int]:
    """The ids of the nodes inside ``if TYPE_CHECKING:`` blocks (imports for annotations only, never run)."""
    ids: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If):
            test = node.test
            name = test.id if isinstance(test, ast.Name) else test.attr if isinstance(test, ast.Attribute) else ""
            if name == "TYPE_CHECKING":
                ids.update(id(n) for sub in node.body for n in ast.walk(sub))
    return ids


def imported_modules(path: Path, known: set[str]) -> set[str]:
    """The modules of ``known`` that ``path`` imports when it runs (at module level or inside functions,
    not under ``TYPE_CHECKING``): ``from pkg import sub`` counts as ``pkg.sub`` when that is a module,
    else as ``pkg``; ``import a.b.c`` as the longest of its prefixes that is a module."""
    tree = ast.parse(path.read_text())
    here = module_name(path).split(".")
    package = here if path.name == "__init__.py" else here[:-1]
    skip = under_type_checking(tree)
    out: set[str] = set()
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            for alias in node.names:
                name = alias.name
                while name and name not in known:
                    name = name.rpartition(".")[0]
                if name:
                    out.add(name)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package[: len(package) - node.level + 1] + ([base] if base else []))
            for alias in node.names:
                full = f"{base}.{alias.name}"
                if full in known:
                    out.add(full)
                elif base in known:
                    out.add(base)
    return out


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in sorted(graph.get(node, ())):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                top = stack.pop()
                on_stack.discard(top)
                component.append(top)
                if top == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def test_no_import_circle_in_prc_slam_or_data_tools():
    """No two modules of prc_slam and data_tools import each other, directly or through others, counting
    the imports inside functions (a lazy import that closes a circle still ties the two modules
    together); ``TYPE_CHECKING`` imports and a module's import of its own parent package do not count."""
    assert circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert circles({"a": {"b"}, "b": set()}) == []
    mods = {**modules("prc_slam"), **modules("data_tools")}
    graph = {
        name: {m for m in imported_modules(path, set(mods)) if m != name and not name.startswith(m + ".")}
        for name, path in mods.items()
    }
    found = circles(graph)
    assert not found, "import circles: " + "; ".join(" <-> ".join(c) for c in found)


def test_the_cli_has_no_per_frame_loop_or_scoring():
    for path in (ROOT / "prc_slam" / "cli").glob("*.py"):
        text = path.read_text()
        for needle in ("ConfusionAccumulator", "objects_found", "for scan in", "dataset[i]", "classify_frames"):
            assert needle not in text, f"{path.name} contains {needle!r}"
