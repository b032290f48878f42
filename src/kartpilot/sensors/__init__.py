"""Frame sources: datasets, recordings and (later) live cameras behind one interface."""
