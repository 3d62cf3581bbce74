"""The package's layout, read from its source: no import circles between modules (lazy imports
inside functions count too), the dataset code knows no agents, and branches on a task's name
live in the task's own module (docs/development.md)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "nmrm_ros"


def _modules() -> dict:
    out = {}
    for f in PACKAGE.rglob("*.py"):
        rel = f.relative_to(PACKAGE.parent).with_suffix("")
        out[".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)] = f
    return out


def _import_graph() -> dict:
    """module -> the nmrm_ros modules it imports anywhere (package __init__ re-exports resolved
    to the module they name where it is one)."""
    mods = _modules()
    edges = {m: set() for m in mods}
    for m, f in mods.items():
        base = m.split(".") if f.name == "__init__.py" else m.split(".")[:-1]
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    parts = base[: len(base) - (node.level - 1)]
                    target = ".".join(parts + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                if target.startswith("nmrm_ros"):
                    for alias in node.names:
                        full = f"{target}.{alias.name}"
                        edges[m].add(full if full in mods else target)
            elif isinstance(node, ast.Import):
                edges[m].update(a.name for a in node.names if a.name.startswith("nmrm_ros"))
    return edges


def _cycles(edges: dict) -> list:
    """Strongly connected components of more than one module (Tarjan), package __init__s left out
    (they re-export; a module importing its package's name is not a circle of code)."""
    mods = _modules()
    nodes = [m for m in edges if mods[m].name != "__init__.py"]
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in edges[v]:
            if w not in index and w in nodes:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in nodes:
        if v not in index:
            visit(v)
    return out


def test_no_import_circles():
    assert _cycles(_import_graph()) == []


def test_the_dataset_code_knows_no_agents_and_the_core_no_ros():
    edges = _import_graph()
    assert not [(a, b) for a in edges for b in edges[a] if a.startswith("nmrm_ros.datasets") and
                b.startswith("nmrm_ros.rl")]
    core = ("nmrm_ros.mil", "nmrm_ros.datasets", "nmrm_ros.tasks", "nmrm_ros.oracles", "nmrm_ros.bags")
    for module, f in _modules().items():
        if module.startswith(core):
            assert not re.search(r"^\s*(import|from) rclpy", f.read_text(), re.M), module


def test_branches_on_a_task_name_live_in_the_task_modules():
    """Outside nmrm_ros/tasks/ no module names a task in a condition (the views draw the zones
    of a task's TaskInfo; their per-task probes and contexts are tables keyed by task)."""
    pattern = re.compile(r'(==|!=| in | not in )\s*\(?\s*"(timer|moving|key|charger|lunar_lander)"'
                         r'|"(timer|moving|key|charger|lunar_lander)"\s*(==|!=)')
    found = {str(f.relative_to(PACKAGE.parent)) for f in PACKAGE.rglob("*.py")
             if "tasks" not in f.relative_to(PACKAGE).parts and pattern.search(f.read_text())}
    assert not found, found


def test_bench_scripts_share_nothing_but_the_library():
    """A bench script imports the package (what a user would call), never another bench script
    or tests/ (installed_check, which stops a bench on a stale install, is the one exception)."""
    bench = PACKAGE.parent / "bench"
    scripts = {f.stem for f in bench.glob("*.py")} - {"installed_check"}
    found = []
    for f in sorted(bench.glob("*.py")):
        for node in ast.walk(ast.parse(f.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else [])
            found += [f"{f.name} imports {n}" for n in names if n.split(".")[0] in scripts]
        if re.search(r"sys\.path\.(insert|append)\(.*tests", f.read_text()):
            found.append(f"{f.name} puts tests/ on sys.path")
    assert not found, found
