"""The input of the static stages (evaluate, drift, integrate) as blocks (``navigate.blocks``): an MCAP
file chunk by chunk (memory independent of its length), any other input (CSV, a Session already
loaded) as one block in memory, and so is a file the blocks cannot take (damaged chunks, a model
reading dT/dt: the stage returns None and reads it whole)."""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import TypeVar

from accellog.core.session import Session
from accellog.flows.stream_input import StreamedSession, can_stream, open_streamed
from accellog.navigate.blocks import Blocks, file_blocks, session_blocks

T = TypeVar("T")
StaticInput = Session | StreamedSession | str | os.PathLike


def run_on_blocks(
    x: StaticInput, run: Callable[[Blocks], T | None], load: Callable[[], Session], *, stream: bool = True
) -> tuple[T, Session | StreamedSession]:
    """(run(the blocks), the input it read: a StreamedSession or the Session). The file's labels are
    read first when x is a path (its time-stamp check rides in run's first pass); load() reads the
    whole session when the file does not stream (or not stream)."""
    if stream and not isinstance(x, Session):
        s = x if isinstance(x, StreamedSession) else None
        if s is None and can_stream(x):
            s = open_streamed(x, observe=False, check_times=False)  # checked in run's first pass
        if s is not None:
            got = run(file_blocks(s.path, s.meta, s.poses))
            if got is not None:
                return got, s
    data = x if isinstance(x, Session) else load()
    return run(session_blocks(data)), data
