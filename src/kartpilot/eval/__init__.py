"""Evaluation against ground truth with the field's metrics (through evo)."""
