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
