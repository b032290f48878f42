"""Perception: features, matching, tracking, stereo depth (and later lanes)."""
