"""Progress bars for commands that can run longer than ~2 s (rich.progress): description, bar,
done/total, elapsed and time left. Drawn on stderr, and only when both stdout and stderr are
terminals and --json was not given, so piped or machine-read output stays clean."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager

Update = Callable[..., None]
"""update(done, total=None): the work done so far (and the total, when it became known)."""


def wanted(json_out: bool = False) -> bool:
    """True when a bar should be drawn: a terminal on stdout and stderr, and no --json."""
    return not json_out and sys.stdout.isatty() and sys.stderr.isatty()


@contextmanager
def progress_bar(
    description: str, total: float | None = None, *, show: bool | None = None
) -> Iterator[Update]:
    """A context giving update(done, total=None); a no-op when not ``show`` (default: ``wanted()``)."""
    if not (wanted() if show is None else show):
        yield lambda done, total=None: None
        return
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    columns = (
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("left"),
        TimeRemainingColumn(),
    )
    with Progress(*columns, console=Console(stderr=True), transient=True) as bar:
        task = bar.add_task(description, total=total)
        last = [0.0]

        def update(done: float, total: float | None = None) -> None:
            now = time.monotonic()
            if now - last[0] < 0.05 and not (total is not None and done >= total):
                return  # callers may report thousands of times a second
            last[0] = now
            if total is not None:
                bar.update(task, total=total)
            bar.update(task, completed=done)

        yield update


class StepBar:
    """A bar that appears at the first update(done, total) and goes away once done >= total: for a
    flow that prints its own lines between long silent steps (the bar is never up while they print)."""

    def __init__(self, description: str, *, show: bool | None = None):
        self.description, self.show = description, show
        self._ctx: AbstractContextManager[Update] | None = None
        self._update: Update | None = None

    def __call__(self, done: float, total: float) -> None:
        update = self._update
        if self._ctx is None or update is None:
            self._ctx = progress_bar(self.description, total, show=self.show)
            self._update = update = self._ctx.__enter__()
        update(done, total)
        if done >= total:
            self.close()

    def close(self) -> None:
        if self._ctx is not None:
            ctx, self._ctx = self._ctx, None
            ctx.__exit__(None, None, None)
