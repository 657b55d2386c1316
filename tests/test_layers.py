"""The identifier's modules import in one direction: presentation (present, report, cli) sits
above diagnosis (diagnose, search, analysis), which never imports it back, and no two modules
import each other in a circle (the effect registry aside: stid.models.effect loads the
built-in effects, which register themselves with it)."""

from __future__ import annotations

import ast
from pathlib import Path

from conftest import REPO

PRESENTATION = ("stid.present", "stid.report", "stid.cli")
DIAGNOSIS = ("stid.diagnose", "stid.search", "stid.analysis")
REGISTRY = "stid.models.effect"


def _imports() -> dict:
    """Module -> the stid modules it imports (anywhere in it, lazily too)."""
    root = REPO / "stid"
    mods = {}
    for p in root.rglob("*.py"):
        parts = p.relative_to(REPO).with_suffix("").parts
        mods[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = p
    graph = {}
    for m, p in mods.items():
        found = set()
        for node in ast.walk(ast.parse(Path(p).read_text())):
            if isinstance(node, ast.ImportFrom) and node.module:
                for a in node.names:
                    full = f"{node.module}.{a.name}"
                    found.add(full if full in mods else node.module)
            elif isinstance(node, ast.Import):
                found.update(a.name for a in node.names)
        graph[m] = {f for f in found if f in mods and f != m}
    return graph


def _under(module: str, roots) -> bool:
    return any(module == r or module.startswith(r + ".") for r in roots)


def test_diagnosis_never_imports_presentation():
    graph = _imports()
    back = [(m, i) for m, deps in graph.items() if _under(m, DIAGNOSIS) for i in deps if _under(i, PRESENTATION)]
    assert not back, back


def test_no_import_circles_but_the_effect_registry():
    graph = _imports()
    effects = {m for m in graph if _under(m, ("stid.effects",))} | {REGISTRY}
    # every module's reach; a circle is a module that reaches itself
    circles = []
    for start in graph:
        seen, todo = set(), list(graph[start])
        while todo:
            m = todo.pop()
            if m in seen:
                continue
            seen.add(m)
            todo.extend(graph[m])
        if start in seen and start not in effects:
            circles.append(start)
    assert not circles, sorted(circles)
