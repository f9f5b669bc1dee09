"""Notes for the user that are not errors (e.g. "truncated file recovered: 41.2 s, 5 holds").

Library code calls ``note(text)``; the CLI prints the pending notes as ``accellog: note: ...`` lines
on stderr when a command succeeds (a failing command prints only its one error line).
"""

from __future__ import annotations

_pending: list[str] = []


def note(text: str) -> None:
    """Queue one line for the user (printed by the CLI on success)."""
    if text not in _pending:
        _pending.append(text)


def take() -> list[str]:
    """The pending notes, oldest first; the queue is emptied."""
    out = list(_pending)
    _pending.clear()
    return out
