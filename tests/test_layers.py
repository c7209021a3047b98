"""The house: the package's folders import one way (no circle between them), and no generic module names the drawer,
which reaches the layers above it through ``Task`` hooks alone."""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# where the package's modules live: the folders setup.cfg installs under the package's namespace
SOURCES = {"sb3_memret": ROOT / "sb3_memret", "sb3_memret.envs": ROOT / "envs", "sb3_memret.callbacks": ROOT / "callbacks"}
DRAWER = re.compile(r"tasks\.drawer|DrawerTask|DEFAULT_TASK")
# where the default task may be named: the task registry, and the one place that sets the commands' default
NAMES_THE_DEFAULT = {"sb3_memret/tasks/__init__.py", "sb3_memret/cli/options.py"}


def modules() -> dict[str, Path]:
    """Every module of the package by dotted name."""
    found = {}
    for package, folder in SOURCES.items():
        for path in folder.rglob("*.py"):
            parts = path.relative_to(folder).with_suffix("").parts
            name = ".".join((package, *parts)).removesuffix(".__init__")
            if package == "sb3_memret" and parts[0] in ("envs", "callbacks"):
                continue
            found[name] = path
    return found


def room(name: str) -> str:
    """The room a module lives in: its folder under the package (``sb3_memret.tasks``), or itself at the root."""
    parts = name.split(".")
    return ".".join(parts[:2])


def imports(path: Path) -> set[str]:
    """The package's modules ``path`` imports, at its top or inside a function."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("sb3_memret"):
            found.add(node.module)
        elif isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names if alias.name.startswith("sb3_memret")}
    return found


def test_the_folders_import_one_way():
    edges: dict[str, set[str]] = {}
    for name, path in modules().items():
        for target in imports(path):
            if room(target) != room(name):
                edges.setdefault(room(name), set()).add(room(target))

    def reaches(start: str, goal: str, seen: set[str]) -> bool:
        return any(nxt == goal or (nxt not in seen and reaches(nxt, goal, seen | {nxt})) for nxt in edges.get(start, ()))

    circles = sorted(a for a in edges if reaches(a, a, {a}))
    assert not circles, f"folders in an import circle: {circles} ({ {a: sorted(edges[a]) for a in circles} })"
    assert "sb3_memret.tasks" in edges and "sb3_memret.cli" in edges  # the graph was read


def test_no_generic_module_names_the_drawer():
    named = {}
    for name, path in modules().items():
        where = path.relative_to(ROOT).as_posix()
        if where.startswith("sb3_memret/tasks/") or where in NAMES_THE_DEFAULT:
            continue
        lines = [i for i, line in enumerate(path.read_text().splitlines(), 1) if DRAWER.search(line)]
        if lines:
            named[where] = lines
    assert not named, f"modules outside tasks/ that name the drawer (file: lines): {named}"
    registry = (ROOT / "sb3_memret/tasks/__init__.py").read_text()
    assert "DEFAULT_TASK" in registry and "tasks.drawer" in registry  # the registry still makes the drawer a task
