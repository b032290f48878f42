"""Decisions above lane following: what the event's scenarios ask of the kart (start on green, keep to the posted
limit, stop before the stop line at red, wait for a pedestrian), from the detections and the measured speed."""
