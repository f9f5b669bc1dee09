"""The Rerun SDK, imported once per process with the cyclic garbage collector paused.

``import rerun`` runs ~500 modules (attrs classes) and creates ~60,000 long-lived objects; with the
collector running, the import triggers collections that scan them again and again (0.04 s of a 1 h
``replay --rrd``). ``rerun_sdk()`` imports it with the collector paused and leaves the collector as
the caller had it. In a one-shot process (the CLI sets FREEZE_AFTER_IMPORT) every object alive is
then frozen (``gc.freeze``): later collections and interpreter shutdown never scan rerun's objects
again (0.2 s of CPU at the exit of a 1 h ``replay --rrd``). A library must not move a user's objects
out of the collector's reach, so by default nothing is frozen.

Unless the user sets ``RUST_LOG``, rerun's own log lines about its file sink (``RUST_LOG_DEFAULT``)
are off: a sink that fails (a full disk) is said once, by ``RunRecording``, as one error line.
"""

from __future__ import annotations

import gc
import os
import sys
from types import ModuleType

RUST_LOG_DEFAULT = "warn,re_log_encoding::rrd=off,re_sdk::recording_stream=off"
"""rerun's log filter when RUST_LOG is unset: warnings, except the file sink's (RunRecording says them)."""
FREEZE_AFTER_IMPORT = False
"""True in the `accellog` command's own process (accellog.cli sets it): gc.freeze() after the import."""


def rerun_sdk() -> ModuleType:
    """The ``rerun`` module, imported with the collector paused on first use (module docstring)."""
    if "rerun" in sys.modules:
        import rerun

        return rerun
    os.environ.setdefault("RUST_LOG", RUST_LOG_DEFAULT)  # read by rerun when it starts logging
    was_on = gc.isenabled()
    gc.disable()
    try:
        import rerun
    finally:
        if was_on:
            gc.enable()
    if FREEZE_AFTER_IMPORT:
        gc.freeze()
    return rerun
