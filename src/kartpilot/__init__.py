"""kartpilot: a camera-only self-driving stack for karts.

The package is laid out by pipeline stage, with imports going one way:
``core`` -> ``sensors`` / ``calibration`` -> ``perception`` -> ``odometry`` ->
``planning`` / ``control`` / ``actuation``; ``sim``, ``record`` and ``eval`` sit
beside them; ``runtime`` and ``cli`` sit on top.
"""

import logging

__version__ = "0.1.0"
__all__ = ["__version__"]

logging.getLogger(__name__).addHandler(logging.NullHandler())
