"""What `record` draws on a terminal: the hold's progress bar is printed as it is (rich would read
"[####----]" as markup and drop it, leaving a garbled line; issue 45, item 4)."""

from __future__ import annotations

import io

from rich.console import Console

from accellog.cli import record
from accellog.core.protocol import pose_spec


def test_hold_progress_bar_is_not_taken_for_markup(monkeypatch):
    buf = io.StringIO()
    monkeypatch.setattr(
        record, "console", Console(file=buf, force_terminal=True, color_system=None, width=100)
    )
    ui = record.TerminalUI()
    pose = pose_spec("-z@0", 10.0)
    ui.holding(pose, 4.0)
    ui.holding(pose, 8.0)
    lines = [x.strip() for x in buf.getvalue().split("\r") if x.strip()]
    assert lines == ["holding -z@0 [########------------]  40%", "holding -z@0 [################----]  80%"]
