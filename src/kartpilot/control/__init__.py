"""Control: pure functions from a tracking error (or a speed error) to actuator commands."""
