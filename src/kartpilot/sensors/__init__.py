"""Frame sources: datasets, recordings, live cameras (synchronised, watched for health) and the gamepad, behind
one interface."""
