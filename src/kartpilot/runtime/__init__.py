"""The top layer: the stack's configuration, the pipelines by name, the loop and one drive session (simulator,
replay or live) with its supervisor, watchdogs and result."""
