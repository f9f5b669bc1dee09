"""`python -m accellog` runs the command line (same as the `accellog` script)."""

import sys

from accellog.cli import main

sys.exit(main())
