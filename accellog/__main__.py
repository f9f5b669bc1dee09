"""`python -m accellog` runs the command line (same as the `accellog` script)."""

from accellog.cli import console

console()
