"""Record and replay: kartpilot's self-describing recording format."""
