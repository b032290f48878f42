"""Simulation: the closed-loop simulator (tracks, karts, dynamics, cameras, referee) and synthetic sequences."""
