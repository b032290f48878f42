"""One root exception with a subclass per stage.

The CLI turns any :class:`KartpilotError` into one line on stderr and a non-zero
exit; anything else is a bug and keeps its traceback.
"""

__all__ = [
    "ActuationError",
    "CalibrationError",
    "ConfigError",
    "DataError",
    "EvaluationError",
    "KartpilotError",
    "OdometryError",
    "PerceptionError",
    "PlanningError",
    "RecordingError",
    "SensorError",
]


class KartpilotError(Exception):
    """Root of every error kartpilot raises on purpose."""


class ConfigError(KartpilotError):
    """A configuration file or value is wrong (unknown key, wrong type, bad value)."""


class DataError(KartpilotError):
    """Input data is missing, unreadable, empty or inconsistent."""


class CalibrationError(KartpilotError):
    """A calibration is missing, malformed or physically implausible."""


class SensorError(KartpilotError):
    """A camera cannot be opened, or does not deliver what the rig says it should."""


class PerceptionError(KartpilotError):
    """A perception stage got input it cannot work on."""


class OdometryError(KartpilotError):
    """Visual odometry cannot go on (not raised for a single bad frame, which is bridged)."""


class PlanningError(KartpilotError):
    """A reference path is missing, unreadable or unusable."""


class RecordingError(KartpilotError):
    """A recording cannot be written or read."""


class ActuationError(KartpilotError):
    """The CAN interface cannot be opened, or a frame is malformed (wrong checksum, unknown message)."""


class EvaluationError(KartpilotError):
    """Trajectories or results cannot be compared."""
