"""Errors that mean "the input is wrong": the CLI prints them as one line and exits non-zero."""

from __future__ import annotations


class AccellogError(Exception):
    """A problem with the user's input or environment, stated in one line: what and where.

    The CLI prints ``accellog: error: <message>`` to stderr and exits with ``exit_code`` (no
    traceback). Raise it with the file name and, where known, the line, pose or sample index.
    """

    exit_code = 2

    def __init__(self, message: str, *, where: str | None = None) -> None:
        self.where = where
        super().__init__(f"{where}: {message}" if where else message)


class InputError(AccellogError):
    """Malformed, missing or inconsistent input data (files, rows, poses, units)."""


class ModelError(AccellogError):
    """A model the data cannot determine (rank, conditioning, too few poses)."""


class DeviceError(AccellogError):
    """The sensor or bus misbehaves (wrong WHO_AM_I, no magnetometer, persistent I2C errors)."""

    exit_code = 3


class DataIntegrityWarning(UserWarning):
    """Part of a file failed its integrity check (CRC) and was skipped or is unverified; the
    message names where. The CLI prints it as one line on stderr."""


def did_you_mean(words, known) -> str:
    """' (did you mean X, Y?)' naming the closest known name of each unknown word (difflib), or ''
    when none is close: the hint an unknown key or option value gets."""
    import difflib

    words = [words] if isinstance(words, str) else list(words)
    hits = [m[0] for w in words if (m := difflib.get_close_matches(w, list(known), n=1))]
    return f" (did you mean {', '.join(hits)}?)" if hits else ""
