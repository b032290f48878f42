"""Every input file comes through one door (issue 56): text through ``core.files.read_text_file`` (and the JSON,
CSV and YAML readers over it), images through ``core.images.read_image``. Those doors name the file in every
error, tell a folder from a missing file, bound the size, the nesting and the pixels, and read other tools'
encodings and line ends. A module that reads a file another way goes around them; this test fails on it, naming
the module, the line and the call."""

from __future__ import annotations

import ast
from pathlib import Path

import kartpilot

DOORS = {"core/files.py", "core/images.py"}
"""The modules that read files themselves."""

FORBIDDEN = {
    ("cv2", "imread"), ("cv2", "imdecode"), ("cv2", "imreadmulti"), ("np", "loadtxt"), ("np", "genfromtxt"),
    ("np", "fromfile"), ("json", "load"), ("json", "loads"), ("yaml", "load"), ("yaml", "safe_load"),
    ("yaml", "full_load"), ("yaml", "SafeLoader"), ("csv", "reader"), ("csv", "DictReader"), ("pd", "read_csv"),
}
"""Readers that take a file (or its text) as it comes: around the doors' checks."""

ALLOWED = {
    ("runtime/webui.py", "json.loads"): "a request's body off the network, not a file: bounded by its own checks",
    ("runtime/webui.py", ".read_bytes()"): "the operator's page, shipped in the package",
    ("sensors/gamepad.py", "os.open"): "the gamepad's device node, not a file",
    ("sim/camera_effects.py", "cv2.imdecode"): "the simulated camera's JPEG, decoded as it was just encoded",
    ("study/spec.py", ".read_bytes()"): "kartpilot's own source files, hashed for the code's version",
}
"""Reads that are not of an input file, each with the reason."""


def around_the_doors(source: str, name: str) -> list[str]:
    """Each call in ``source`` that reads a file around the doors: ``NAME:LINE: CALL``."""
    found: list[tuple[int, int, str]] = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.Call):
            continue
        func = node.func
        call = ""
        if isinstance(func, ast.Attribute) and isinstance(func.value, ast.Name):
            if (func.value.id, func.attr) in FORBIDDEN:
                call = f"{func.value.id}.{func.attr}"
            elif func.value.id == "os" and func.attr == "open":
                call = "os.open"
        if isinstance(func, ast.Attribute) and func.attr in ("read_text", "read_bytes"):
            call = f".{func.attr}()"
        # Path.open() takes no argument or a mode first; another object's open(...) (a class's constructor, a
        # clip's source) takes something else
        is_open = (isinstance(func, ast.Name) and func.id == "open") or (
            isinstance(func, ast.Attribute) and func.attr == "open" and not (
                isinstance(func.value, ast.Name) and func.value.id == "os") and (
                not node.args or isinstance(node.args[0], ast.Constant)))
        if is_open:
            args = node.args[1:] if isinstance(func, ast.Name) else node.args
            modes = [a for a in args[:1] if isinstance(a, ast.Constant)] + [
                k.value for k in node.keywords if k.arg == "mode" and isinstance(k.value, ast.Constant)]
            mode = str(modes[0].value) if modes else "r"
            if not any(c in mode for c in "wax"):
                call = "open() to read"
        if call and (name, call) not in ALLOWED:
            found.append((node.lineno, node.col_offset, f"{name}:{node.lineno}: {call}"))
    return [line for _, _, line in sorted(found)]


def test_no_module_reads_a_file_around_the_doors() -> None:
    root = Path(kartpilot.__file__).parent
    found = []
    for path in sorted(root.rglob("*.py")):
        name = path.relative_to(root).as_posix()
        if name not in DOORS:
            found += around_the_doors(path.read_text(encoding="utf-8"), name)
    assert not found, ("these read a file around kartpilot.core.files / kartpilot.core.images (read_text_file, "
                       "read_json_file, parse_csv, iter_csv_file, parse_yaml, read_image):\n" + "\n".join(found))


def test_the_check_fails_on_a_reader_that_goes_around_the_door() -> None:
    """The architecture test's own test: each way around the doors is caught, and the ways through are not."""
    around = '''
import csv, json, cv2, numpy as np, yaml
image = cv2.imread("frame.png")
times = np.loadtxt("times.txt")
data = json.load(open("labels.json"))
config = yaml.safe_load(path.read_text())
with path.open() as handle:
    rows = list(csv.DictReader(handle))
with open("x.bin", "rb") as raw:
    pass
'''
    found = around_the_doors(around, "sensors/new_reader.py")
    print("\n".join(found))
    assert [line.split(": ", 1)[1] for line in found] == [
        "cv2.imread", "np.loadtxt", "json.load", "open() to read", "yaml.safe_load", ".read_text()", "open() to read",
        "csv.DictReader", "open() to read"]  # in the order of the source
    through = '''
from kartpilot.core.files import read_json_file, read_text_file, write_text_atomic
from kartpilot.core.images import read_image
image = read_image(path)
data = read_json_file(path)
with path.open("w") as out:
    out.write("x")
'''
    assert around_the_doors(through, "sensors/new_reader.py") == []
