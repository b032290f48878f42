"""Types, geometry, configuration and errors shared by every stage."""
