"""The calibration file: the Calibration type, its typed sections and their JSON round trip."""
