"""Imports run one way, from the pipeline's first stage to the top: a package imports only packages below it.

core < calibration < sensors < perception < odometry < planning, actuation < control; beside one another
behaviour (the event's decisions, above control), sim, record and eval; then runtime (the loop, one drive
session), then study (sweeps of whole runs), then cli. Within a package anything goes."""

import ast
from pathlib import Path

import kartpilot

RANK = {"core": 0, "calibration": 1, "sensors": 2, "perception": 3, "odometry": 4, "planning": 5, "actuation": 5,
        "control": 6, "behaviour": 7, "sim": 7, "record": 7, "eval": 7, "runtime": 8, "study": 9, "cli": 10}


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("kartpilot."):
            found.add(node.module.split(".")[1])
        elif isinstance(node, ast.Import):
            found |= {a.name.split(".")[1] for a in node.names if a.name.startswith("kartpilot.")}
    return found


def test_no_import_runs_back_up():
    root = Path(kartpilot.__file__).parent
    packages = {p.name for p in root.iterdir() if p.is_dir() and (p / "__init__.py").is_file()}
    assert packages == set(RANK), "a new package needs its place in the layering"
    upward = []
    for path in sorted(root.rglob("*.py")):
        package = path.relative_to(root).parts[0]
        if package not in RANK:
            continue
        for imported in _imports(path) - {package}:
            if RANK[imported] >= RANK[package]:
                upward.append(f"{path.relative_to(root)} imports kartpilot.{imported}")
    assert not upward, "\n".join(upward)


def _module_graph() -> dict[str, set[str]]:
    """Each kartpilot module and the kartpilot modules it imports, at its top or inside a function."""
    root = Path(kartpilot.__file__).parent
    modules = {}
    for path in root.rglob("*.py"):
        parts = path.relative_to(root.parent).with_suffix("").parts
        modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    graph = {}
    for name, path in modules.items():
        found = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("kartpilot."):
                found |= {node.module} | {f"{node.module}.{a.name}" for a in node.names}
            elif isinstance(node, ast.Import):
                found |= {a.name for a in node.names}
        graph[name] = (found & set(modules)) - {name, "kartpilot"}
    return graph


def test_no_two_modules_import_each_other():
    """No circle of imports between modules, within a package too (``study/spec`` and ``study/jobs`` were one,
    the import hidden inside a function): a module's place in the stack is where its imports put it."""
    graph = _module_graph()
    assert "kartpilot.study.spec" in graph["kartpilot.study.jobs"]
    circles = []
    for start in sorted(graph):
        seen, todo = set(), list(graph[start])
        while todo:
            module = todo.pop()
            if module == start:
                circles.append(start)
                break
            if module not in seen:
                seen.add(module)
                todo.extend(graph[module])
    assert not circles, f"modules on a circle of imports: {circles}"


def test_the_study_spec_names_the_jobs_the_registry_runs():
    from kartpilot.study.jobs import JOBS
    from kartpilot.study.spec import JOB_NAMES

    assert tuple(JOBS) == JOB_NAMES


def test_the_runtime_layer_stays_small_functions():
    """runtime/ is where the stack is put together, and where it got hard to carry on: no function there over 60
    lines or 8 parameters (issue 18's bound)."""
    root = Path(kartpilot.__file__).parent / "runtime"
    too_big = []
    for path in sorted(root.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = (node.end_lineno or node.lineno) - node.lineno + 1
                arguments = node.args.args + node.args.kwonlyargs
                count = len([a for a in arguments if a.arg not in ("self", "cls")])
                count += bool(node.args.vararg) + bool(node.args.kwarg)
                if lines > 60 or count > 8:
                    too_big.append(f"{path.name}: {node.name} ({lines} lines, {count} parameters)")
    assert not too_big, "\n".join(too_big)
