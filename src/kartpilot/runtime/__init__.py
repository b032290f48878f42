"""The top layer: the whole-stack configuration and (later) the fixed-rate loop."""
