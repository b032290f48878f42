"""What every benchmark script shares."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any


def camera_name(results: dict[str, Any]) -> str:
    """``real`` or ``perfect``: the simulated camera a result's JSON says it drove through (its ``camera``, the
    effects' defaults then); a JSON from before the field was through the perfect camera."""
    camera = results.get("camera")
    return "real" if camera and camera.get("jpeg_quality", 0) > 0 else "perfect"


def write_json(path: str | Path, data: Any) -> None:
    """Write a benchmark's results (creating the folder) and say where."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=2, default=float) + "\n")
    print(f"wrote {path}")
