"""Simulation: synthetic sequences now, the closed-loop simulator later."""
