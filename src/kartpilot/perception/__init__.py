"""Perception: features, matching, tracking, stereo depth, lane boundaries, VLAD and the road's top view."""
