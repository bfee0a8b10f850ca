"""Arrows point one way: every import (also those inside functions) of every module, checked against
the layers of the README's layout, and no import circle inside ``data_tools``."""

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


def test_no_import_circle_in_data_tools():
    mods = modules("data_tools")
    graph = {
        name: {m for m in imports(path) if m in mods and m != name and not name.startswith(m + ".")}
        for name, path in mods.items()
    }
    # a package's __init__ re-exporting its submodules is not a circle
    graph = {n: {m for m in deps if not (n == m.rsplit(".", 1)[0])} for n, deps in graph.items()}
    state: dict[str, int] = {}
    cycles: list[list[str]] = []

    def visit(node: str, stack: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                cycles.append([*stack[stack.index(nxt) :], nxt])
            elif nxt not in state:
                visit(nxt, [*stack, nxt])
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])
    assert not cycles, "import circles: " + "; ".join(" -> ".join(c) for c in cycles)


def test_the_cli_has_no_per_frame_loop_or_scoring():
    for path in (ROOT / "prc_slam" / "cli").glob("*.py"):
        text = path.read_text()
        for needle in ("ConfusionAccumulator", "objects_found", "for scan in", "dataset[i]", "classify_frames"):
            assert needle not in text, f"{path.name} contains {needle!r}"
