"""Camera calibration and stereo rectification (depends on ``core`` only)."""
