"""One bad-input case run the way every bad-input test judges it: the command refuses in one line
(`accellog: error: ...`, non-zero exit, no traceback), names what it must, writes nothing, leaves
every input as it was and spends < 5 s of CPU before the refusal."""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path

from accellog.cli import main


def snapshot(d: Path) -> dict[str, tuple]:
    """Name -> (mode, size, mtime_ns, first 64 KiB of a regular file) of every entry below d,
    links unfollowed (big sparse inputs are not read whole)."""
    out = {}
    for p in sorted(d.rglob("*")):
        st = p.lstat()
        head = p.open("rb").read(65536) if p.is_file() and not p.is_symlink() else None
        out[str(p.relative_to(d))] = (st.st_mode, st.st_size, st.st_mtime_ns, head)
    return out


def assert_refused(argv: Sequence[str], folder: Path, capsys, needles: Sequence[str] = ()) -> str:
    """Run argv; assert the one-line refusal (module doc) with every needle in it; return the line."""
    before = snapshot(folder)
    capsys.readouterr()
    t0 = time.process_time()
    rc = main(list(argv))
    cpu_s = time.process_time() - t0
    err = capsys.readouterr().err.strip()
    assert rc != 0, f"exit 0: {err}"
    assert "Traceback" not in err, err
    assert err.startswith("accellog: error: ") and "\n" not in err, err
    for n in needles:
        assert n in err, (n, err)
    assert snapshot(folder) == before, "files were written, changed or left behind (or user code ran)"
    assert cpu_s < 5.0, f"{cpu_s:.1f} s of CPU before the refusal"
    return err
