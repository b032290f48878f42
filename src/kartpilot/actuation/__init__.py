"""Actuation: the kart's CAN messages (a DBC file), the command sender and the ECUs' status."""
