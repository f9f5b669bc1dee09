"""accellog version (one place; the package root and every file writer read it)."""

__version__ = "0.1.0"
