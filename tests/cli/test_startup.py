"""``kartpilot`` starts in a blink: building its parser imports none of what the commands run, a command imports
only what it needs, and the names the parser offers are the library's own.

The import tests read ``python -X importtime`` in a fresh interpreter, so they see every module a statement pulls,
whatever this test process has loaded already. Speed itself is measured in ``benchmarks/startup.py``."""

from __future__ import annotations

import importlib
import subprocess
import sys

import pytest
from tests.conftest import subcommands

from kartpilot.cli import arguments
from kartpilot.cli.main import build_parser

HEAVY = ("sklearn", "matplotlib", "pandas", "scipy.stats", "ray", "rerun", "onnxruntime", "can", "cantools",
         "optuna", "panda3d", "torch")
"""Libraries that cost a command a tenth of a second to seconds to import, none of which ``--help`` needs."""


def imported_modules(statement: str) -> set[str]:
    """Every module ``statement`` imports in a fresh interpreter (from ``-X importtime``)."""
    done = subprocess.run([sys.executable, "-X", "importtime", "-c", statement], capture_output=True, text=True,
                          timeout=120, check=True)
    return {line.split("|")[-1].strip() for line in done.stderr.splitlines() if line.startswith("import time:")}


def _pulled(modules: set[str], libraries: tuple[str, ...]) -> list[str]:
    return sorted(lib for lib in libraries if any(m == lib or m.startswith(lib + ".") for m in modules))


def test_building_the_parser_imports_only_the_standard_library_and_the_cli() -> None:
    modules = imported_modules("import kartpilot.cli.main; kartpilot.cli.main.build_parser()")
    assert "kartpilot.cli.arguments" in modules  # the statement did run
    assert not _pulled(modules, HEAVY), f"kartpilot's parser pulls {_pulled(modules, HEAVY)}"
    assert not _pulled(modules, ("numpy", "cv2", "scipy", "yaml")), "the parser needs none of the numeric stack"
    ours = sorted(m for m in modules if m.startswith("kartpilot."))
    assert ours == ["kartpilot.cli", "kartpilot.cli.arguments", "kartpilot.cli.main", "kartpilot.cli.values",
                    "kartpilot.core", "kartpilot.core.errors"], ours


def test_the_lanes_command_loads_no_learning_plotting_or_cluster_library() -> None:
    """``kartpilot lanes IMAGE``: the lane pipeline, its readers and writers; scikit-learn (place recognition),
    matplotlib (plots), Ray, Rerun and onnxruntime load only in the functions that use them."""
    modules = imported_modules("import kartpilot.cli.commands")
    heavy = ("sklearn", "matplotlib", "pandas", "scipy.stats", "ray", "rerun", "onnxruntime", "optuna", "panda3d")
    assert not _pulled(modules, heavy), f"the lanes command's module pulls {_pulled(modules, heavy)}"


def test_the_guard_sees_a_heavy_import() -> None:
    """The import guard itself: a statement that does import a heavy library is caught."""
    assert _pulled(imported_modules("import kartpilot.eval.plots; kartpilot.eval.plots.pyplot()"), HEAVY) == \
        ["matplotlib"]


def test_every_subcommand_names_a_handler_that_exists() -> None:
    commands = subcommands(build_parser())
    assert {"lanes", "detect", "sim", "drive", "calibrate ground", "study run", "odometry kitti"} <= set(commands)
    for name, parser in commands.items():
        handler = parser.get_default("handler")
        assert handler is not None, f"`kartpilot {name}` has no handler"
        module, function = arguments.handler_target(handler)
        assert callable(getattr(importlib.import_module(module), function)), f"`kartpilot {name}`: {module}.{function}"


@pytest.mark.parametrize(("names", "registry"), [
    (arguments.LANE_PRESETS, "kartpilot.runtime.lane_policy:LANE_PRESETS"),
    (arguments.PIPELINES, "kartpilot.runtime.pipelines:PIPELINES"),
    (arguments.SCENARIOS, "kartpilot.sim.scenarios:SCENARIOS"),
    (arguments.VEHICLES, "kartpilot.core.vehicle:VEHICLES"),
    (arguments.STUDIES, "kartpilot.study.spec:BUILT_IN"),
])
def test_the_parser_offers_the_names_the_library_defines(names: tuple[str, ...], registry: str) -> None:
    module, name = registry.split(":")
    defined = getattr(importlib.import_module(module), name)
    assert sorted(names) == sorted(defined), f"kartpilot.cli.arguments's names differ from {registry}"
